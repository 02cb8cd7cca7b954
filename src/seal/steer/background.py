"""Run an async verifier in the background while the steering loop keeps sampling.

The loop itself is synchronous (it waits on pool workers); verifications are coroutines
(HTTP calls to a VLM, or an instant oracle check). A private event loop on its own thread
runs them, and the loop polls plain `concurrent.futures.Future`s - no async leaks upward.
"""

from __future__ import annotations

import asyncio
import threading
import time
from concurrent.futures import Future

from seal.verify.base import Verdict, VerifyRequest


class BackgroundVerifier:
    def __init__(self, verifier):
        self.verifier = verifier
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="seal-verify", daemon=True)
        self._thread.start()

    def submit(self, request: VerifyRequest) -> Future:
        """Start verifying now; the future resolves to a `Verdict` (exceptions become unknown)."""
        return asyncio.run_coroutine_threadsafe(self._run(request), self._loop)

    async def _run(self, request: VerifyRequest) -> Verdict:
        start = time.perf_counter()
        try:
            verdict = await self.verifier.verify(request)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # a verifier failure must not end the episode
            verdict = Verdict(None, f"unknown: verifier error {type(exc).__name__}: {exc}")
        verdict.extra.setdefault("wall_s", time.perf_counter() - start)
        return verdict

    def close(self) -> None:
        if self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5)
        if not self._loop.is_running():
            self._loop.close()

    def __enter__(self) -> "BackgroundVerifier":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
