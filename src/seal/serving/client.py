"""`OpenpiPolicy`: a `ReasoningPolicy` backed by an openpi websocket policy server.

It speaks exactly what ``openpi_client.WebsocketClientPolicy`` speaks (same msgpack-numpy
frames, same keys), but owns the socket itself because steering needs what that class does
not have: a timeout on every reply, connect retries with backoff, a reconnect when the server
drops the connection, and several connections for K concurrent requests.

The transforms are explicit and live in `seal.serving.protocol`: `observation_request` (a SEAL
`Observation` -> openpi's LIBERO keys), `batch_request`, `parse_reply` (shapes and keys checked,
naming expected vs got). K candidates are K observations, sent

- ``batched``: as one request with a leading batch axis, when the metadata advertises it;
- ``concurrent``: as K requests over up to ``max_connections`` sockets at once;
- ``sequential``: one after the other on one socket.

``auto`` takes batched when offered, else concurrent (``seal bench serve`` measures all three).

A server that does not reason (plain pi0) gets its sub-plans from a `Planner`
(`seal.policies.planners`), and the engine ends its sub-plans on the step budget or when the
verifier accepts (``thinks = False``).
"""

from __future__ import annotations

import inspect
import os
import logging
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Sequence

import websockets
import websockets.sync.client as ws_client
from openpi_client import msgpack_numpy

from seal.errors import InvalidInput
from seal.policies.base import ActionChunk, Reasoning
from seal.serving import protocol as P
from seal.serving.protocol import PolicyServerError, ProtocolError
from seal.sim.observation import Observation

log = logging.getLogger(__name__)

TRANSPORTS = ("auto", "batched", "concurrent", "sequential")
# websockets >= 17 warns unless a directly used connection says so explicitly; older ones lack the flag
_LEGACY = {"legacy": True} if "legacy" in inspect.signature(ws_client.connect).parameters else {}
PROMPTS = ("task", "subplan")


@dataclass(frozen=True)
class ClientConfig:
    host: str = "127.0.0.1"
    port: int = 8000
    connect_timeout_s: float = 10.0  # per attempt: TCP + handshake + metadata
    connect_retries: int = 3  # extra attempts after the first
    backoff_s: float = 0.5  # before the first retry; doubles each retry
    max_backoff_s: float = 8.0
    request_timeout_s: float = 30.0  # one reply; a hung server fails here instead of hanging the run
    transport: str = "auto"
    max_connections: int = 16  # sockets used by the concurrent transport
    prompt: str = "task"  # servers that do not reason: send the task instruction or the current sub-plan
    # sent as "Authorization: Api-Key <key>" (openpi's header); repr=False keeps it out of logs and reprs
    api_key: str | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.transport not in TRANSPORTS:
            raise InvalidInput(f"unknown transport {self.transport!r}; valid: {', '.join(TRANSPORTS)}")
        if self.prompt not in PROMPTS:
            raise InvalidInput(f"unknown prompt source {self.prompt!r}; valid: {', '.join(PROMPTS)}")
        if self.connect_timeout_s <= 0 or self.request_timeout_s <= 0:
            raise InvalidInput(f"timeouts must be > 0, got connect {self.connect_timeout_s}, "
                               f"request {self.request_timeout_s}")
        if self.connect_retries < 0 or self.backoff_s < 0 or self.max_connections < 1:
            raise InvalidInput("need connect_retries >= 0, backoff_s >= 0, max_connections >= 1")

    @property
    def uri(self) -> str:
        return self.host if self.host.startswith("ws") else f"ws://{self.host}:{self.port}"


class _Lane:
    """One websocket to the server: connect (with retries), one request -> one reply."""

    def __init__(self, config: ClientConfig):
        self.config = config
        self.ws: ws_client.ClientConnection | None = None
        self._packer = msgpack_numpy.Packer()
        self.closed = False  # closed by its owner: never reconnect (e.g. a thread still waiting at Ctrl-C)

    def connect(self) -> dict:
        cfg, last = self.config, None
        for attempt in range(cfg.connect_retries + 1):
            if attempt:
                time.sleep(min(cfg.backoff_s * 2 ** (attempt - 1), cfg.max_backoff_s))
            try:
                # proxy=None: a policy server sits beside the simulator; never route it via HTTP_PROXY
                headers = {"Authorization": f"Api-Key {cfg.api_key}"} if cfg.api_key else None
                self.ws = ws_client.connect(cfg.uri, compression=None, max_size=None, proxy=None,
                                            additional_headers=headers,
                                            open_timeout=cfg.connect_timeout_s, close_timeout=1.0, **_LEGACY)
                metadata = msgpack_numpy.unpackb(self.ws.recv(timeout=cfg.connect_timeout_s))
                return metadata
            except websockets.InvalidStatus as exc:
                if exc.response.status_code in (401, 403):  # retrying cannot fix a refused key
                    self.close()
                    raise PolicyServerError(
                        f"the policy server at {cfg.uri} refused the connection (HTTP {exc.response.status_code}): "
                        + ("its API key was not accepted" if cfg.api_key else "it needs an API key")
                        + "; set OPENPI_API_KEY") from None
                last = exc
                self.close()
                log.info("policy server %s: connect attempt %d failed: %s", cfg.uri, attempt + 1, exc)
            except (OSError, TimeoutError, websockets.WebSocketException, ValueError) as exc:
                last = exc
                self.close()
                log.info("policy server %s: connect attempt %d failed: %s", cfg.uri, attempt + 1, exc)
        raise PolicyServerError(f"cannot reach the policy server at {cfg.uri}: {cfg.connect_retries + 1} attempt(s) "
                                f"with a {cfg.connect_timeout_s:g} s timeout failed; last error: "
                                f"{type(last).__name__}: {last}. Is `seal serve` (or the openpi server) running?")

    def call(self, request: dict) -> Any:
        cfg = self.config
        data = self._packer.pack(request)
        for attempt in range(2):  # a dropped connection is reopened once and the request resent
            if self.closed:
                raise PolicyServerError(f"the connection to {cfg.uri} was closed by this client")
            if self.ws is None:
                self.connect()
            try:
                self.ws.send(data)
                raw = self.ws.recv(timeout=cfg.request_timeout_s)
            except TimeoutError:
                self.close()  # a late reply must not be read as the answer to the next request
                raise PolicyServerError(f"no reply from the policy server at {cfg.uri} within "
                                        f"{cfg.request_timeout_s:g} s (request_timeout_s); gave up on this "
                                        "connection") from None
            except websockets.ConnectionClosed as exc:
                self.close()
                if attempt:
                    raise PolicyServerError(f"the policy server at {cfg.uri} closed the connection twice in a "
                                            f"row while answering ({exc})") from None
                log.warning("policy server %s closed the connection (%s); reconnecting", cfg.uri, exc)
                continue
            if isinstance(raw, str):
                return raw  # an error report; parse_reply raises with its text
            try:
                return msgpack_numpy.unpackb(raw)
            except Exception as exc:
                raise ProtocolError(f"reply from {cfg.uri} is not valid msgpack-numpy: "
                                    f"{type(exc).__name__}: {exc}") from None
        raise AssertionError("unreachable")

    def close(self) -> None:
        if self.ws is not None:
            try:
                self.ws.close()
            except Exception:  # closing a broken socket may itself fail; it is gone either way
                pass
            self.ws = None


class OpenpiPolicy:
    """A `ReasoningPolicy` on an openpi-protocol server (pi0, a reasoning VLA, or `seal serve`).

    ``task`` (e.g. "libero_10/0") is needed only by servers hosting a privileged policy (the
    scripted expert): they build their policy for it. ``planner`` is needed only by servers
    that do not reason.
    """

    def __init__(self, config: ClientConfig, *, task: str | None = None, planner=None):
        self.config = config
        self._executor: ThreadPoolExecutor | None = None
        self._lanes = [_Lane(config)]
        self.metadata = self._lanes[0].connect()
        try:
            self.info = P.ServerInfo.from_metadata(self.metadata)
        except ProtocolError:
            self.close()
            raise
        self.session = uuid.uuid4().hex
        self.planner = planner
        self.thinks = self.info.reasoning  # a policy that never emits <think> (the engine checks)
        # A server that wants its cameras at another size than openpi's 224 (a VLA trained at 64 px)
        # says so; the steering loop then renders both cameras at that size (as for the policy in-process).
        self.image_size = (self.info.image_size if self.info.images and self.info.image_size != P.IMAGE_SIZE
                           else None)
        self.transport = self._pick_transport(config.transport)
        self._atoms: list[str] | None = None
        self._reasoning: Reasoning | None = None
        self._acted = False
        self.requests = 0
        if not self.info.reasoning and planner is None:
            self.close()
            raise InvalidInput(f"the policy server at {config.uri} does not return reasoning (its metadata has no "
                               "seal.reasoning); give a planner: annotations or vlm")
        if self.info.privileged and task is None:
            self.close()
            raise InvalidInput(f"the policy server at {config.uri} hosts a privileged (scripted) policy; "
                               "give task='libero_10/0' (suite/id)")
        if self.info.control and task is not None:
            answer = self._control("configure", task=task)
            atoms = answer.get("privileged_atoms") if isinstance(answer, dict) else None
            if self.info.privileged:
                if not isinstance(atoms, list) or not all(isinstance(a, str) for a in atoms):
                    self.close()
                    raise ProtocolError(f"'configure' reply: expected 'privileged_atoms' (a list of strings), "
                                        f"got {answer!r}")
                self._atoms = atoms

    # ---- ReasoningPolicy ----------------------------------------------------------------------
    def privileged_atoms(self) -> list[str] | None:
        return self._atoms

    def reset(self, instruction: str, seed: int) -> None:
        self._reasoning, self._acted = None, False
        if self.info.control:
            self._control("reset", instruction=instruction, seed=int(seed))
        if self.planner is not None:
            self.planner.reset(instruction)

    def reason(self, obs: Observation) -> Reasoning:
        if not self.info.reasoning:
            # One planner step per sub-plan: a new one only after the last one was acted on.
            if self._reasoning is None or self._acted:
                self._reasoning, self._acted = self.planner.next(obs), False
            return self._reasoning
        req = self._tag(P.observation_request(obs, info=self.info), row=0)
        reply = P.parse_reply(self._lanes[0].call(req), None, want_reasoning=True)[0]
        self.requests += 1
        self._reasoning = P.read_reasoning(reply.reasoning)
        return self._reasoning

    def begin(self, k: int) -> None:
        if self.info.control:
            self._control("begin", k=int(k))

    def act(self, obs_batch: Sequence[Observation], reasoning: Reasoning,
            rows: Sequence[int] | None = None) -> list[ActionChunk]:
        rows = list(range(len(obs_batch))) if rows is None else list(rows)
        if len(rows) != len(obs_batch):
            raise InvalidInput(f"act() got {len(obs_batch)} observations for {len(rows)} rows")
        if not obs_batch:
            return []
        self._acted = True
        reqs = [self._tag(self._obs_request(o, reasoning), row=r) for o, r in zip(obs_batch, rows)]
        if self.transport == "batched":
            replies = []
            step = self.info.max_batch
            for i in range(0, len(reqs), step):
                part = reqs[i : i + step]
                req = P.batch_request(part)
                req[P.ROWS] = rows[i : i + step]
                req.update({k: part[0][k] for k in (P.REASONING, P.SESSION) if k in part[0]})
                replies += P.parse_reply(self._lanes[0].call(req), len(part))
                self.requests += 1
        elif self.transport == "concurrent" and len(reqs) > 1:
            replies = self._concurrent(reqs)
        else:
            replies = [P.parse_reply(self._lanes[0].call(r), None)[0] for r in reqs]
            self.requests += len(reqs)
        return [ActionChunk(actions=r.actions, think=r.think) for r in replies]

    # ---- plumbing -----------------------------------------------------------------------------
    def _obs_request(self, obs: Observation, reasoning: Reasoning) -> dict:
        req = P.observation_request(obs, info=self.info)
        if self.info.reasoning:
            req[P.REASONING] = reasoning.text()  # act on this sub-plan, do not reason anew
        elif self.config.prompt == "subplan" and reasoning.now:
            req[P.PROMPT] = reasoning.now
        return req

    def _tag(self, req: dict, row: int) -> dict:
        if self.info.control:  # only SEAL servers see SEAL's keys
            req[P.SESSION], req[P.ROW] = self.session, int(row)
        return req

    def _control(self, what: str, **fields) -> dict:
        reply = self._lanes[0].call({P.CONTROL: what, P.SESSION: self.session, **fields})
        if isinstance(reply, str):
            raise PolicyServerError(f"the policy server refused {what!r}: {reply.strip()[-2000:]}")
        if not isinstance(reply, dict) or reply.get("ok") is not True:
            raise ProtocolError(f"{what!r} reply: expected a map with 'ok': true, got {reply!r}")
        return reply

    def _concurrent(self, reqs: list[dict]) -> list[P.Reply]:
        n_lanes = min(len(reqs), self.config.max_connections)
        while len(self._lanes) < n_lanes:
            self._lanes.append(_Lane(self.config))  # connects lazily, in its worker thread
        if self._executor is None or self._executor._max_workers < n_lanes:
            if self._executor is not None:
                self._executor.shutdown(wait=True)
            self._executor = ThreadPoolExecutor(max_workers=n_lanes, thread_name_prefix="seal-openpi")

        def run_lane(j: int) -> list[tuple[int, P.Reply]]:
            lane = self._lanes[j]
            return [(i, P.parse_reply(lane.call(reqs[i]), None)[0]) for i in range(j, len(reqs), n_lanes)]

        futures = [self._executor.submit(run_lane, j) for j in range(n_lanes)]
        out: dict[int, P.Reply] = {}
        for f in futures:  # re-raises the first lane's error (timeouts bound every wait)
            out.update(f.result())
        self.requests += len(reqs)
        return [out[i] for i in range(len(reqs))]

    def _pick_transport(self, wanted: str) -> str:
        if wanted == "batched" and not self.info.batch:
            self.close()
            raise InvalidInput(f"the policy server at {self.config.uri} does not accept batched requests "
                               "(metadata seal.batch); use transport concurrent or sequential")
        if wanted == "auto":
            return "batched" if self.info.batch else "concurrent"
        return wanted

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
        for lane in self._lanes:
            lane.closed = True
            lane.close()

    def __enter__(self) -> "OpenpiPolicy":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def remote_policy(spec, task, *, seed: int = 0) -> OpenpiPolicy:
    """`seal.policies.make_policy`'s ``remote`` entry: a server at ``spec.host:spec.port``, plus a
    planner (``spec.planner``) when it does not reason. ``seed`` goes to the server at ``reset``."""
    from seal.policies.planners import make_planner

    planner = None if not spec.planner else make_planner(spec.planner, spec=task, annotations=spec.annotations,
                                                         model=spec.planner_model, base_url=spec.base_url)
    config = ClientConfig(host=spec.host, port=spec.port, transport=spec.transport,
                          request_timeout_s=spec.request_timeout, prompt=spec.prompt,
                          api_key=os.environ.get("OPENPI_API_KEY") or None)  # secrets: environment only
    return OpenpiPolicy(config, task=task.key, planner=planner)
