"""Serve any SEAL `ReasoningPolicy` over openpi's websocket protocol (plus SEAL's extension).

Like openpi's ``WebsocketPolicyServer``: the metadata goes out on connect, then every binary
frame is a request and gets one reply; errors go back as a text frame. Unlike it, a bad
request (missing key, wrong shape) gets its error message and the connection stays open -
only an unexpected exception closes it (code 1011), as openpi does.

It enforces what its metadata advertises (docs/serving.md): at most ``max_batch`` rows, frames of
the advertised sizes, finite inputs, requests up to ``max_request_bytes`` (a larger one closes its
connection, code 1009), known tasks in ``configure``; and it never sends NaN or Inf actions.

Stateful policies (the scripted expert keeps its plan and per-row random streams) live in
*sessions*: a client names its session in every message (``seal/session``), so the several
connections a client opens to send K observations concurrently share one policy. Without a
session name a connection gets a session of its own. Policy calls run in a worker thread,
one at a time per session, so the event loop keeps reading other connections meanwhile.
"""

from __future__ import annotations

import asyncio
import dataclasses
import errno
import hmac
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import websockets
import websockets.asyncio.server as ws_server
from openpi_client import msgpack_numpy

from seal.errors import InvalidInput, SealError
from seal.policies.base import PREDICT_HORIZON, ActionChunk
from seal.serving import protocol as P

log = logging.getLogger(__name__)

PolicyFactory = Callable[[str], Any]  # task key (e.g. "libero_10/0") -> a ReasoningPolicy


def check_port(port: Any) -> int:
    """A TCP port to listen on: 1..65535, or 0 for any free one (the OS picks it)."""
    if not isinstance(port, int) or isinstance(port, bool) or not 0 <= port <= 65535:
        raise InvalidInput(f"port must be in 1..65535 (or 0: any free port), got {port!r}")
    return port


def task_spec(task: Any):
    """The `TaskSpec` a task key ('libero_10/0': suite/id) names; an `InvalidInput` that lists the
    valid suites and ids otherwise."""
    from seal.sim.suites import SUITES, get_task

    suite, _, index = str(task).partition("/")
    if suite not in SUITES or not index.isdigit():
        raise InvalidInput(f"unknown task {task!r}; valid: SUITE/ID, e.g. 'libero_10/0', with SUITE one of "
                           f"{', '.join(SUITES)}")
    try:
        return get_task(suite, int(index))
    except InvalidInput as exc:
        raise InvalidInput(f"unknown task {task!r}: {exc}") from None


def policy_server(name: str, options, *, seed: int = 0, max_batch: int = 64, plain: bool = False,
                  task: str = "") -> tuple[PolicyFactory, P.ServerInfo, dict, str | None]:
    """What `seal serve` serves for a registered policy: (factory, info, metadata, default task).

    The learned VLA loads its weights once, here, and shares them across sessions; the scripted
    expert builds a policy for whatever task a client configures. Any other policy gets a session
    of its own from `seal.policies.make_policy` and describes itself (reasoning, privileged state,
    image size) through one built now for ``task``, which it therefore needs."""
    from seal.policies import POLICIES
    from seal.policies.options import ScriptedOptions, VLAOptions

    meta = {"policy": name, "action_dim": 7, "action_horizon": 16}
    if isinstance(options, VLAOptions):  # loads (and checks) the checkpoint now: a bad one fails before listening
        factory = vla_factory(options.policy_ckpt, seed=seed)
        meta.update(checkpoint=factory.source, weights_sha256=factory.manifest.get("weights_sha256", "")[:12],
                    reasoning_model=factory.model.cfg.reasoning, image_size=factory.model.cfg.image_size)
        return factory, vla_info(factory, max_batch, plain=plain), meta, task  # it reads pixels: no task needed
    if isinstance(options, ScriptedOptions):
        meta["knobs"] = options.knobs
        return scripted_factory(options.knobs, seed=seed), scripted_info(max_batch, plain=plain), meta, task or None
    if not task:
        raise InvalidInput(f"seal serve --policy {name}: give --task (a task it is built for now, to describe itself)")
    from seal.policies import make_policy
    from seal.policies.base import images_for

    def make(key: str):
        return make_policy(name, POLICIES.options_of(name, options), task_spec(key), seed=seed)

    probe = make(task)
    try:
        atoms = probe.privileged_atoms()
        images = images_for(probe, atoms)
        info = P.ServerInfo(reasoning=probe.thinks and not plain, batch=not plain, max_batch=max_batch, control=True,
                            privileged=atoms is not None, images=bool(images),
                            **({"image_size": images} if images and images is not True else {}),
                            version=P.PROTOCOL_VERSION)
    finally:
        probe.close()
    return make, info, meta, task


def scripted_factory(knobs: str = "misaligned", seed: int = 0) -> PolicyFactory:
    """The scripted expert for whatever task a client configures (built through the policy
    registry, like every other policy)."""
    from seal.policies import make_policy
    from seal.policies.options import ScriptedOptions

    options = ScriptedOptions(knobs=knobs)  # fail on a bad name now, not at the first client

    def make(task: str):
        return make_policy("scripted", options, task_spec(task), seed=seed)

    return make


def scripted_info(max_batch: int = 64, *, plain: bool = False) -> P.ServerInfo:
    """``plain``: behave like a pi0 server - no reasoning or think in replies, no batching; the
    expert then follows its own hidden plan for the whole task (a stand-in for pi0 in tests)."""
    return P.ServerInfo(reasoning=not plain, batch=not plain, max_batch=max_batch, control=True, privileged=True,
                        images=False, version=P.PROTOCOL_VERSION)


def vla_factory(ckpt: str = "", seed: int = 0) -> PolicyFactory:
    """A learned VLA checkpoint (``ckpt`` as in ``--policy vla:PATH``: '' the shipped reasoning
    model, 'twin', or a directory). The weights are loaded once, here, so a missing or broken
    checkpoint fails before the server listens; each session gets its own `VLAPolicy` (its own
    episode seed and per-row noise streams) over the shared model. It reads pixels, not scene
    state, so it needs no task; a client that configures one must still name a known task."""
    from seal.policies.vla.checkpoint import load_checkpoint
    from seal.policies.vla.locate import resolve_checkpoint
    from seal.policies.vla.policy import VLAPolicy

    where = resolve_checkpoint(ckpt)
    model, tok, manifest = load_checkpoint(where)

    def make(task: str):
        return VLAPolicy(model, tok, seed=seed, source=str(where), manifest=manifest)

    make.model, make.source, make.manifest = model, str(where), manifest  # what the server describes
    return make


def vla_info(factory: PolicyFactory, max_batch: int = 64, *, plain: bool = False) -> P.ServerInfo:
    """A reasoning checkpoint reasons over the wire like the scripted server; the twin cannot, so
    it never does (its clients bring a planner). ``plain`` as for `scripted_info`. The server
    advertises the image size the model was trained at; 224-px frames are resized to it."""
    cfg = factory.model.cfg
    return P.ServerInfo(reasoning=cfg.reasoning and not plain, batch=not plain, max_batch=max_batch, control=True,
                        privileged=False, images=True, image_size=cfg.image_size, version=P.PROTOCOL_VERSION)


@dataclass
class _Session:
    policy: Any = None
    task: str = ""
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)


class PolicyServer:
    def __init__(self, factory: PolicyFactory, info: P.ServerInfo, *, host: str = "127.0.0.1", port: int = 0,
                 metadata: dict | None = None, default_task: str | None = None, max_sessions: int = 32,
                 api_key: str | None = None):
        """Refuses (`InvalidInput`) what it could not serve as advertised: a port outside 0..65535,
        ``max_batch < 1``, an image size a client would refuse, an unknown ``default_task``. Unless
        ``info`` says otherwise, ``max_request_bytes`` is `protocol.request_limit` of its settings."""
        if info.max_batch < 1:
            raise InvalidInput(f"max_batch must be >= 1, got {info.max_batch}")
        if not 16 <= info.image_size <= 1024:
            raise InvalidInput(f"image_size must be in 16..1024 px, got {info.image_size}")
        if not info.max_request_bytes:
            limit = P.request_limit(info.max_batch if info.batch else 1, info.image_size)
            info = dataclasses.replace(info, max_request_bytes=limit)
        if default_task:  # '' (the VLA's default): clients that do not configure get a policy without a task
            task_spec(default_task)
        self.factory, self.info, self.host, self.port = factory, info, host, check_port(port)
        self._api_key = api_key  # when set, the handshake must carry "Authorization: Api-Key <key>"
        self.metadata = {**(metadata or {}), "seal": info.to_metadata()}
        self.default_task = default_task  # lets a plain openpi client (no configure) use the server
        self.max_sessions = max_sessions
        self._sessions: OrderedDict[str, _Session] = OrderedDict()
        self.requests = 0

    # ---- running ---------------------------------------------------------------------------
    async def serve(self, stop: asyncio.Future, on_ready: Callable[[int], None] | None = None) -> None:
        """Listen until ``stop`` is done. A port in use (or any address that cannot be bound) is an
        `InvalidInput` naming it. Requests over ``max_request_bytes`` close their connection (1009)."""
        try:
            server = await ws_server.serve(self._handler, self.host, self.port, compression=None,
                                           max_size=self.info.max_request_bytes,
                                           process_request=self._process_request)
        except OSError as exc:
            raise _listen_error(self.host, self.port, exc) from None
        async with server:
            self.port = server.sockets[0].getsockname()[1]
            if on_ready is not None:
                on_ready(self.port)
            await stop
            server.close(close_connections=True)
            await server.wait_closed()

    def serve_forever(self, on_ready: Callable[[int], None] | None = None) -> None:
        """Until SIGINT/SIGTERM, then close every connection and return (no traceback)."""

        async def main():
            loop = asyncio.get_running_loop()
            stop = loop.create_future()
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.add_signal_handler(sig, lambda: stop.done() or stop.set_result(None))
            await self.serve(stop, on_ready)

        asyncio.run(main())

    # ---- one connection ----------------------------------------------------------------------
    def _process_request(self, connection, request):
        """Health check first (never needs a key), then the API key if one is required."""
        import http

        reply = _health_check(connection, request)
        if reply is None and self._api_key and not _key_ok(request.headers.get("Authorization"), self._api_key):
            return connection.respond(http.HTTPStatus.UNAUTHORIZED, "missing or wrong API key\n")
        return reply

    async def _handler(self, ws: ws_server.ServerConnection) -> None:
        own_session = f"conn-{id(ws)}"
        packer = msgpack_numpy.Packer()
        await ws.send(packer.pack(self.metadata))
        try:
            async for message in ws:
                try:
                    if isinstance(message, str):
                        raise P.ProtocolError("requests must be binary msgpack frames, got a text frame")
                    try:
                        req = msgpack_numpy.unpackb(message)
                    except Exception as exc:
                        raise P.ProtocolError(f"request is not valid msgpack: {type(exc).__name__}: {exc}") from None
                    reply = await self._dispatch(req, own_session)
                except SealError as exc:  # the client's fault: say why, keep serving
                    await ws.send(f"{type(exc).__name__}: {exc}")
                    continue
                except Exception:  # ours: report it and close, as openpi's server does
                    await ws.send(traceback.format_exc())
                    await ws.close(code=1011, reason="internal server error; traceback in the previous frame")
                    log.exception("policy server error")
                    return
                await ws.send(packer.pack(reply))
        except websockets.ConnectionClosed:
            pass
        finally:
            self._sessions.pop(own_session, None)

    async def _dispatch(self, req: Any, own_session: str) -> dict:
        if not isinstance(req, dict):
            raise P.ProtocolError(f"a request must be a msgpack map, got {type(req).__name__}")
        self.requests += 1
        sid = req.get(P.SESSION, own_session)
        if not isinstance(sid, str):
            raise P.ProtocolError(f"request {P.SESSION!r} must be a string, got {sid!r}")
        if P.CONTROL in req:
            return await self._control(P.check_control(req), req, sid)
        session = self._session(sid)
        if session.policy is None:
            if self.default_task is None:
                raise P.ProtocolError(f"no policy in session {sid!r} yet: send {{'{P.CONTROL}': 'configure', "
                                      "'task': 'libero_10/0'}} first")
            await self._configure(session, self.default_task)
        obs = P.parse_request(req, needs_images=self.info.images, needs_scene=self.info.privileged,
                              image_size=self.info.image_size, max_batch=self.info.max_batch if self.info.batch else 0)
        n = req.get(P.BATCH)
        rows = P.request_rows(req, n)
        given = req.get(P.REASONING) if self.info.reasoning else None
        reasoning = P.read_reasoning(given) if given is not None else None
        if reasoning is None and n is not None and _thinks(session.policy):
            raise P.ProtocolError(f"a batched request ({P.BATCH!r}) must carry 'reasoning' to act on")
        async with session.lock:
            t0 = time.perf_counter()
            reasoning, chunks = await asyncio.to_thread(_infer, session.policy, obs, reasoning, rows)
            infer_ms = (time.perf_counter() - t0) * 1e3
        bad = [r for r, c in zip(rows, chunks) if not np.all(np.isfinite(c.actions))]
        if bad:  # never send them: a client would execute them
            raise P.PolicyServerError("the policy produced NaN or Inf actions" + (f" for rows {bad}" if n else "")
                                      + "; none are sent (a broken checkpoint, or an input it cannot handle)")
        reply: dict[str, Any] = {"server_timing": {"infer_ms": infer_ms}}
        if n is None:
            reply[P.ACTIONS], reply[P.THINK] = chunks[0].actions, bool(chunks[0].think)
        else:
            reply[P.ACTIONS] = np.stack([c.actions for c in chunks])
            reply[P.THINK] = np.array([c.think for c in chunks], dtype=bool)
        if self.info.reasoning:
            reply[P.REASONING] = reasoning.text()
        else:  # a plain server says nothing about its plan
            del reply[P.THINK]
        return reply

    async def _control(self, ctrl: str, req: dict, sid: str) -> dict:
        session = self._session(sid)
        if ctrl == "configure":
            task = req.get("task")
            if not isinstance(task, str):
                raise P.ProtocolError(f"'configure' needs 'task' (a string like 'libero_10/0'), got {task!r}")
            await asyncio.to_thread(task_spec, task)  # every server refuses an unknown task, even the VLA's
            await self._configure(session, task)
            atoms = session.policy.privileged_atoms() if hasattr(session.policy, "privileged_atoms") else None
            return {"ok": True, "task": task, "privileged_atoms": atoms}
        if session.policy is None:
            if self.default_task is None:
                raise P.ProtocolError(f"{ctrl!r} before 'configure' in session {sid!r}")
            await self._configure(session, self.default_task)
        async with session.lock:
            if ctrl == "reset":
                instruction, seed = req.get("instruction"), req.get("seed", 0)
                if not isinstance(instruction, str) or not isinstance(seed, int):
                    raise P.ProtocolError(f"'reset' needs 'instruction' (string) and 'seed' (int), got "
                                          f"{instruction!r}, {seed!r}")
                session.policy.reset(instruction, seed=seed)
            else:  # begin
                k = req.get("k")
                if not isinstance(k, int) or isinstance(k, bool) or k < 1:
                    raise P.ProtocolError(f"'begin' needs 'k' (a positive int), got {k!r}")
                session.policy.begin(k)
        return {"ok": True}

    async def _configure(self, session: _Session, task: str) -> None:
        async with session.lock:
            session.policy = await asyncio.to_thread(self.factory, task)
            session.task = task

    def _session(self, sid: str) -> _Session:
        session = self._sessions.get(sid)
        if session is None:
            session = self._sessions[sid] = _Session()
            while len(self._sessions) > self.max_sessions:  # forget the least recently used
                self._sessions.popitem(last=False)
        self._sessions.move_to_end(sid)
        return session


def _listen_error(host: str, port: int, exc: OSError) -> InvalidInput:
    if exc.errno == errno.EADDRINUSE:
        return InvalidInput(f"cannot listen on {host}:{port}: port {port} is already in use (another server?); "
                            "choose another port, or 0 for any free one")
    return InvalidInput(f"cannot listen on {host}:{port}: {exc.strerror or exc}")


def _thinks(policy) -> bool:
    return bool(getattr(policy, "thinks", True))


def _infer(policy, obs, reasoning, rows) -> tuple[Any, list[ActionChunk]]:
    """A reply's content. Without given reasoning the policy reasons first (as a reasoning VLA
    writes <think>...<act> before its actions), then acts as a fresh single attempt. A policy
    that never thinks (the VLA twin, a pi0) has no reasoning pass: it acts on its prompt within
    the attempts the client started (``begin``), like a pi0 server sampling a chunk."""
    if reasoning is None and not _thinks(policy):
        return None, policy.act(obs, policy.reason(obs[0]), rows=rows)
    if reasoning is None:
        reasoning = policy.reason(obs[0])
        if reasoning.finished:
            return reasoning, [ActionChunk(np.zeros((PREDICT_HORIZON, 7)), think=True)]
        policy.begin(rows[0] + 1)
    return reasoning, policy.act(obs, reasoning, rows=rows)


def _health_check(connection, request):
    """``GET /healthz`` answers 200 without a websocket handshake (openpi's server does the same)."""
    import http

    if request.path == "/healthz":
        return connection.respond(http.HTTPStatus.OK, "OK\n")
    return None


def _key_ok(header: str | None, key: str) -> bool:
    """``Api-Key <key>`` (openpi's client) or ``Bearer <key>``; constant-time comparison."""
    scheme, _, given = (header or "").partition(" ")
    return scheme.lower() in ("api-key", "bearer") and hmac.compare_digest(given.strip().encode(), key.encode())


# ---------------------------------------------------------------------------- in a thread / a process


class ServerThread:
    """A `PolicyServer` on its own event loop in a background thread (tests, benchmarks)."""

    def __init__(self, server: PolicyServer):
        self.server = server
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="seal-serve", daemon=True)
        self._error: BaseException | None = None

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        self._stop = self._loop.create_future()
        try:
            self._loop.run_until_complete(self.server.serve(self._stop, lambda port: self._ready.set()))
        except BaseException as exc:  # noqa: BLE001 - e.g. a port in use: raised again by __enter__
            self._error = exc
            self._ready.set()

    def __enter__(self) -> "ServerThread":
        self._thread.start()
        if not self._ready.wait(30):
            raise RuntimeError("policy server thread did not start within 30 s")
        if self._error is not None:  # it could not listen
            self._thread.join()
            self._loop.close()
            raise self._error
        return self

    @property
    def port(self) -> int:
        return self.server.port

    def stop(self) -> None:
        """Close every connection and stop serving (safe to call from any thread, and twice)."""
        if self._thread.is_alive():
            self._loop.call_soon_threadsafe(lambda: self._stop.done() or self._stop.set_result(None))
            self._thread.join(timeout=15)

    def __exit__(self, *exc) -> None:
        self.stop()
        if not self._thread.is_alive():
            self._loop.close()


class ServerProcess:
    """``seal serve ... --port 0`` as a child process; the port comes from its first stdout line."""

    def __init__(self, args: list[str], *, startup_timeout_s: float = 60.0):
        self.args, self.startup_timeout_s = args, startup_timeout_s
        self.proc: subprocess.Popen | None = None
        self.port = 0

    def __enter__(self) -> "ServerProcess":
        cmd = [sys.executable, "-m", "seal.cli", "serve", "--host", "127.0.0.1", "--port", "0", *self.args]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=os.environ.copy())
        ready: dict = {}

        def read_port() -> None:  # the first JSON line with a port; anything else printed before is skipped
            for line in self.proc.stdout:
                try:
                    event = json.loads(line)
                except ValueError:
                    continue
                if isinstance(event, dict) and "port" in event:
                    ready.update(event)
                    return

        reader = threading.Thread(target=read_port, daemon=True)
        reader.start()
        reader.join(self.startup_timeout_s)
        if "port" not in ready:
            self.stop()
            raise RuntimeError(f"`seal serve {' '.join(self.args)}` did not report a port within "
                               f"{self.startup_timeout_s:g} s (exit code {self.proc.poll()})")
        self.port = int(ready["port"])
        return self

    def stop(self, sig: int = signal.SIGINT, timeout: float = 15.0) -> int | None:
        """Ask it to stop as Ctrl-C would; kill it only if it does not within ``timeout``."""
        if self.proc is None or self.proc.poll() is not None:
            return None if self.proc is None else self.proc.returncode
        self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            return None

    def __exit__(self, *exc) -> None:
        self.stop()
        if self.proc is not None and self.proc.stdout is not None:
            self.proc.stdout.close()
