"""Run an async verifier in the background while the steering loop keeps sampling.

The loop itself is synchronous (it waits on pool workers); verifications are coroutines
(HTTP calls to a VLM, or an instant oracle check). A private event loop on its own thread
runs them, and the loop polls plain `concurrent.futures.Future`s - no async leaks upward.

Failures are sorted here, so that none passes silently:

- permanent (`seal.errors.VerifierUnavailable`: a wrong key, model or URL, a server that is down)
  stays an exception; the loop re-raises it when it reads the future, which stops the run with
  the reason (a run of "execute candidate 0" labelled as a verified method would be worse);
- transient (an unknown verdict whose ``extra["error"]`` says the service failed past its
  retries, or a ConnectionError/TimeoutError raised by a verifier) is an unknown verdict, and
  counted: ``errors`` out of ``calls``, and per round (`start_round`): a round whose finished
  verifications all got no answer was decided without the verifier, and an episode where most
  such rounds were is ``mostly_unavailable``;
- anything else a verifier raises is a bug: it propagates like a permanent error (in `seal eval`
  the trial becomes an error row with its traceback).

`submit` starts a verification at once (arrival order); `submit_together` starts a group in one
turn of the event loop, so a verifier that batches what arrives together (the learned one) judges
the group as one batch whatever the threads' timing (slot order: one group per chunk boundary).
"""

from __future__ import annotations

import asyncio
import threading
import time
from concurrent.futures import CancelledError, Future

from seal.errors import VerifierUnavailable
from seal.verify.base import Verdict, VerifyRequest

# Exceptions a verifier may raise that are worth no more than an unknown verdict.
TRANSIENT = (ConnectionError, TimeoutError, asyncio.TimeoutError)


class BackgroundVerifier:
    def __init__(self, verifier):
        self.verifier = verifier
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="seal-verify", daemon=True)
        self._thread.start()
        # Written on the verifier thread only; read by the loop once the episode is over.
        self.calls = 0  # verifications that finished, with an answer or an error
        self.errors = 0  # ...that ended with no answer: the verifier was unavailable for them
        self.last_error = ""
        self._round = 0
        self._rounds: dict[int, list[bool]] = {}  # round -> answered? per finished verification

    def start_round(self) -> None:
        """Verifications submitted from now on belong to a new sampling round."""
        self._round += 1

    @property
    def rounds_unavailable(self) -> int:
        """Rounds with verifications, none of which got an answer."""
        return sum(not any(answers) for answers in self._rounds.values())

    @property
    def mostly_unavailable(self) -> bool:
        """In more than half of the rounds that asked the verifier, it never answered."""
        return self.rounds_unavailable * 2 > len(self._rounds)

    def submit(self, request: VerifyRequest) -> Future:
        """Start verifying now; the future resolves to a `Verdict` (a transient failure is an
        unknown verdict with ``extra["error"]``) or raises a permanent error."""
        return asyncio.run_coroutine_threadsafe(self._run(request, self._round), self._loop)

    def submit_together(self, requests: list[VerifyRequest]) -> list[Future]:
        """Start verifying ``requests`` in the same turn of the event loop, in their order, so a
        batching verifier sees them as one batch (its make-up, and with it the last bits of each
        probability, is then no matter of timing). Futures as `submit`'s.

        One coroutine creates every task before any runs: tasks start in creation order. (Gating
        tasks created one by one on an event was not enough: a task created after the gate opened
        skips the wait and runs before the earlier ones, which wake a turn later.)"""
        round_ = self._round

        async def start_all() -> list[asyncio.Task]:
            return [asyncio.ensure_future(self._run(r, round_)) for r in requests]

        tasks = asyncio.run_coroutine_threadsafe(start_all(), self._loop).result()
        # Awaiting a task from a thread-safe future keeps `Future.cancel()` working: cancelling
        # the waiter cancels the task it waits on.
        return [asyncio.run_coroutine_threadsafe(_wait(t), self._loop) for t in tasks]

    async def _run(self, request: VerifyRequest, round_: int = 0) -> Verdict:
        start = time.perf_counter()
        try:
            verdict = await self.verifier.verify(request)
        except asyncio.CancelledError:
            raise
        except VerifierUnavailable:
            raise
        except TRANSIENT as exc:  # one flaky call must not end the episode; it is counted below
            why = f"{type(exc).__name__}: {exc}"
            verdict = Verdict(None, f"unknown: verifier error {why}", extra={"error": why})
        self.calls += 1
        answered = not (verdict.success is None and verdict.extra.get("error"))
        self._rounds.setdefault(round_, []).append(answered)
        if not answered:
            self.errors += 1
            self.last_error = str(verdict.extra["error"])
        verdict.extra.setdefault("wall_s", time.perf_counter() - start)
        return verdict

    def close(self) -> None:
        if self._loop.is_running():
            # Cancel what is still in flight (an early exit, or a run stopped by a permanent error)
            # so no verification is left half-done in a loop that is about to close.
            done = asyncio.run_coroutine_threadsafe(_cancel_pending(), self._loop)
            try:
                done.result(timeout=5)
            except (TimeoutError, CancelledError):
                pass  # a verifier that ignores cancellation for 5 s is abandoned with its loop
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5)
        if not self._loop.is_running():
            self._loop.close()

    def __enter__(self) -> "BackgroundVerifier":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


async def _cancel_pending() -> None:
    tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)


async def _wait(task: asyncio.Task) -> Verdict:
    return await task
