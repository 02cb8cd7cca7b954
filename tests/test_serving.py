"""Policy servers over openpi's websocket protocol, on loopback.

The client is tested against `seal serve` (a real child process, and in-thread servers) on the
real LIBERO simulator, and against small real websocket servers that misbehave on purpose:
malformed replies, dropped connections, silence.
"""

from __future__ import annotations

import json
import threading
import time
from contextlib import contextmanager
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest
import websockets.sync.server as ws_sync_server
from websockets.exceptions import ConnectionClosed
from openpi_client import msgpack_numpy

from seal.errors import InvalidInput
from seal.policies.base import Reasoning, parse_reasoning
from seal.policies.expert.policy import FailureKnobs
from seal.policies.planners import AnnotationPlanner, PlannerError, VLMPlanner, parse_plan_answer
from seal.serving import protocol as P
from seal.serving.client import ClientConfig, OpenpiPolicy, _Lane
from seal.serving.server import PolicyServer, ServerProcess, ServerThread, scripted_factory, scripted_info
from seal.sim.pool import EnvPool
from seal.sim.suites import get_task
from seal.steer.config import SteerConfig
from seal.steer.engine import Steerer
from seal.steer.run import expert_policy
from seal.steer.trace import Trace, read_trace
from seal.verify.oracle import OracleVerifier

BOOK = get_task("libero_10", 5)  # two sub-plans, ~90 steps: the quickest LIBERO-10 task
FAST = dict(connect_timeout_s=2.0, connect_retries=1, backoff_s=0.05, request_timeout_s=10.0)


@pytest.fixture(scope="module")
def pool():
    with EnvPool(BOOK, k=4, workers=2) as p:
        yield p


@pytest.fixture(scope="module")
def obs(pool):
    """The book task's first observation: images and the expert's privileged scene."""
    pool.reset(0)
    atoms = expert_policy(BOOK, FailureKnobs()).privileged_atoms()
    return pool.observe([0], images=True, privileged_atoms=atoms)[0]


def _scripted(knobs="misaligned", **kw) -> PolicyServer:
    return PolicyServer(scripted_factory(knobs), scripted_info(**kw))


# ---------------------------------------------------------------------------- the wire format


def test_reasoning_text_round_trips_for_every_libero10_plan():
    from seal.policies.expert.plan import plan_task

    for i in range(10):
        plans = tuple(p.text for p in plan_task(get_task("libero_10", i)))
        for j in range(len(plans) + 1):
            r = Reasoning(plans, plans[:j], plans[j] if j < len(plans) else "")
            assert parse_reasoning(r.text()) == r
    with pytest.raises(InvalidInput, match="three lines"):
        parse_reasoning("pick up the book")
    with pytest.raises(InvalidInput, match="not one of the plans"):
        parse_reasoning("Plans: 1. a. 2. b.\nWhat has been done: c.\nNow I need to do: b.")
    with pytest.raises(InvalidInput, match="must be a string, got int"):
        parse_reasoning(3)
    # on the wire, a text that does not parse is the peer's protocol error
    assert P.read_reasoning(r.text()) == r
    with pytest.raises(P.ProtocolError, match="three lines"):
        P.read_reasoning("pick up the book")


def test_privileged_scene_survives_the_wire(obs):
    wire = msgpack_numpy.unpackb(msgpack_numpy.packb(P.scene_to_wire(obs.scene)))
    scene = P.scene_from_wire(wire)
    assert scene.facts == obs.scene.facts and scene.joints_of == obs.scene.joints_of
    assert set(scene.bodies) == set(obs.scene.bodies) and set(scene.sites) == set(obs.scene.sites)
    np.testing.assert_array_equal(scene.bodies["black_book_1"].lo, obs.scene.bodies["black_book_1"].lo)
    # the expert acts identically on the decoded scene
    chunks = []
    for s in (obs.scene, scene):
        expert = expert_policy(BOOK, FailureKnobs.misaligned(), seed=3)
        o = P.Observation(state=obs.state, prompt=obs.prompt, scene=s)
        r = expert.reason(o)
        expert.begin(2)
        chunks.append(np.stack([c.actions for c in expert.act([o, o], r)]))
    np.testing.assert_array_equal(chunks[0], chunks[1])
    del wire["bodies"]
    with pytest.raises(P.ProtocolError, match=r"missing keys \['bodies'\]"):
        P.scene_from_wire(wire)


# ---------------------------------------------------------------------------- against seal serve


def test_steered_episode_against_a_seal_serve_process_and_clean_ctrl_c(pool, tmp_path):
    with ServerProcess(["--knobs", "misaligned"]) as server:
        with OpenpiPolicy(ClientConfig(port=server.port, **FAST), task=BOOK.key) as policy:
            assert policy.info.reasoning and policy.info.privileged and policy.transport == "batched"
            assert policy.privileged_atoms() == expert_policy(BOOK, FailureKnobs()).privileged_atoms()
            with Trace(tmp_path / "trace.jsonl") as trace:
                result = Steerer(pool, policy, OracleVerifier(), SteerConfig(method="seal", k=4),
                                 trace=trace).run(0)
        assert result.success and not result.sim_error
        assert result.subplans == ["pick up the book", "place it in the back compartment of the caddy"]
        commits = [e for e in read_trace(tmp_path / "trace.jsonl") if e["event"] == "commit"]
        assert commits and all(c["verdict"]["success"] for c in commits)
        assert policy.requests >= 5
        t0 = time.perf_counter()
        code = server.stop()  # SIGINT, as Ctrl-C sends it
        assert code == 0 and time.perf_counter() - t0 < 10
        last = json.loads(server.proc.stdout.read().strip().splitlines()[-1])
        assert last["event"] == "stopped" and last["requests"] >= policy.requests


def test_remote_chunks_equal_in_process_chunks_for_every_transport(obs):
    """Same seed, same calls: the remote expert's chunks are the in-process expert's, bit for bit,
    whether K observations go batched, over concurrent sockets or one after another."""
    expert = expert_policy(BOOK, FailureKnobs.misaligned(), seed=0)
    expert.reset(BOOK.instruction, seed=11)
    r = expert.reason(obs)
    expert.begin(1)  # what the server does after reasoning, to answer with actions too
    expert.act([obs], r, rows=[0])
    expert.begin(4)
    want = np.stack([c.actions for c in expert.act([obs] * 4, r, rows=[0, 1, 2, 3])])
    assert not np.allclose(want[0], want[1])  # rows are distinct random attempts
    with ServerThread(_scripted()) as srv:
        for transport in ("batched", "concurrent", "sequential"):
            with OpenpiPolicy(ClientConfig(port=srv.port, transport=transport, **FAST), task=BOOK.key) as policy:
                policy.reset(BOOK.instruction, seed=11)
                assert policy.reason(obs) == r
                policy.begin(4)
                got = np.stack([c.actions for c in policy.act([obs] * 4, r, rows=[0, 1, 2, 3])])
                np.testing.assert_array_equal(got, want, err_msg=transport)
                # a subset of rows, as when some candidates have finished
                part = policy.act([obs, obs], r, rows=[3, 1])
                assert len(part) == 2 and all(c.actions.shape == (16, 7) for c in part)


def test_openpi_reference_client_talks_to_seal_serve(obs):
    from openpi_client.websocket_client_policy import WebsocketClientPolicy

    with ServerThread(_scripted()) as srv:
        client = WebsocketClientPolicy(host="127.0.0.1", port=srv.port)
        assert client.get_server_metadata()["seal"]["reasoning"] is True
        assert client.infer({P.CONTROL: "configure", "task": BOOK.key})["ok"] is True
        req = P.observation_request(obs, info=P.ServerInfo(privileged=True))
        reply = client.infer(req)
        assert reply["actions"].shape == (16, 7) and reply["think"] is False
        assert P.read_reasoning(reply["reasoning"]).now == "pick up the book"
        client._ws.close()


def test_api_key_is_required_checked_and_never_shown():
    """openpi's header both ways; a refused key fails at once (no retries), /healthz stays open."""
    from urllib.request import urlopen

    from openpi_client.websocket_client_policy import WebsocketClientPolicy

    key = "s3cret-key"
    server = PolicyServer(scripted_factory("clean"), scripted_info(), api_key=key)
    with ServerThread(server) as srv:
        assert urlopen(f"http://127.0.0.1:{srv.port}/healthz", timeout=5).status == 200
        slow = dict(FAST, connect_retries=3, backoff_s=2.0)
        for given, says in ((None, "it needs an API key"), ("wrong", "its API key was not accepted")):
            t0 = time.perf_counter()
            with pytest.raises(P.PolicyServerError, match=f"HTTP 401.*{says}.*OPENPI_API_KEY"):
                OpenpiPolicy(ClientConfig(port=srv.port, api_key=given, **slow))
            assert time.perf_counter() - t0 < 2.0  # no backoff: retrying cannot fix a key
        config = ClientConfig(port=srv.port, api_key=key, **FAST)
        assert key not in repr(config)
        with OpenpiPolicy(config, task=BOOK.key) as policy:
            assert policy.metadata["seal"]["reasoning"] is True
        client = WebsocketClientPolicy(host="127.0.0.1", port=srv.port, api_key=key)  # openpi's own client
        assert client.infer({P.CONTROL: "configure", "task": BOOK.key})["ok"] is True
        client._ws.close()


def test_server_names_what_is_wrong_with_a_request_and_keeps_serving(obs):
    with ServerThread(_scripted()) as srv:
        lane = _Lane(ClientConfig(port=srv.port, **FAST))
        assert lane.connect()["seal"]["privileged"] is True
        req = P.observation_request(obs, info=P.ServerInfo(privileged=True))
        assert "send {'seal/control': 'configure'" in lane.call(req)
        assert lane.call({P.CONTROL: "configure", "task": "libero_10/99"}).startswith("InvalidInput")
        assert lane.call({P.CONTROL: "configure", "task": BOOK.key})["ok"] is True
        bad = dict(req, **{P.IMAGE: np.zeros((100, 100, 3), np.uint8)})
        assert "expected uint8 array of shape (224, 224, 3), got uint8 (100, 100, 3)" in lane.call(bad)
        assert "missing keys ['seal/scene']" in lane.call({k: v for k, v in req.items() if k != P.SCENE})
        # this server needs no cameras, but what comes is checked: both cameras or neither, each a sane frame
        wrist_only = {k: v for k, v in req.items() if k != P.IMAGE}
        wrist_only[P.WRIST] = np.zeros((4096, 64, 3), np.uint8)
        assert "has 'observation/wrist_image' but not 'observation/image': send both cameras or neither" in lane.call(
            wrist_only)
        assert "valid: configure, reset, begin" in lane.call({P.CONTROL: "explode"})
        assert lane.call(req)["actions"].shape == (16, 7)  # the same connection still works
        lane.close()


# ---------------------------------------------------------------------------- servers that do not reason


def test_plain_server_with_annotation_planner_ends_subplans_on_verifier_acceptance(pool, obs, tmp_path):
    with ServerThread(PolicyServer(scripted_factory("clean"), scripted_info(plain=True))) as srv:
        cfg = ClientConfig(port=srv.port, **FAST)
        with pytest.raises(InvalidInput, match="does not return reasoning.*give a planner"):
            OpenpiPolicy(cfg, task=BOOK.key)
        planner = AnnotationPlanner.for_task(BOOK)
        with OpenpiPolicy(cfg, task=BOOK.key, planner=planner) as policy:
            assert not policy.thinks and policy.transport == "concurrent"
            config = SteerConfig(method="seal", k=2, check_every=10)
            with Trace(tmp_path / "trace.jsonl") as trace:
                result = Steerer(pool, policy, OracleVerifier(), config, trace=trace).run(0)
    assert result.success and result.subplans == list(planner.plans)
    events = read_trace(tmp_path / "trace.jsonl")
    picks = [e for e in events if e["event"] == "commit"]
    # the pick sub-plan ended when a mid-rollout check passed, long before its 200-step budget
    assert picks[0]["ended_by"] == "verified" and picks[0]["steps"] < 100
    assert [e["text"] for e in events if e["event"] == "subplan"] == list(planner.plans)


def test_annotation_planner_sources(tmp_path):
    path = tmp_path / "plans.json"
    path.write_text(json.dumps({BOOK.key: ["pick up the book", "put it in the caddy"],
                                "open the drawer": ["open the top drawer"]}))
    planner = AnnotationPlanner.from_json(path, BOOK.key)
    assert [planner.next(None).now for _ in range(3)] == ["pick up the book", "put it in the caddy", ""]
    planner.reset("")
    assert planner.next(None) == Reasoning(("pick up the book", "put it in the caddy"), (), "pick up the book")
    assert AnnotationPlanner.from_json(path, "libero_10/1", "open the drawer").plans == ("open the top drawer",)
    with pytest.raises(InvalidInput, match="no sub-plans for task 'libero_10/2'"):
        AnnotationPlanner.from_json(path, "libero_10/2")
    from seal.datasets.lerobot import Episode, LeRobotWriter

    with LeRobotWriter(tmp_path / "ds") as writer:
        writer.add(Episode(instruction=BOOK.instruction, agent_images=np.zeros((2, 224, 224, 3), np.uint8),
                           wrist_images=np.zeros((2, 224, 224, 3), np.uint8), states=np.zeros((2, 8), np.float32),
                           actions=np.zeros((2, 7), np.float32), subplans=["grab the book", "drop it in the caddy"],
                           critical_frames=[0, 1]))
    assert AnnotationPlanner.from_dataset(tmp_path / "ds", BOOK.instruction).plans == ("grab the book",
                                                                                       "drop it in the caddy")
    with pytest.raises(InvalidInput, match="no annotated episode"):
        AnnotationPlanner.from_dataset(tmp_path / "ds", "juggle")


KEY = "sk-planner-test-7c1d-DO-NOT-LEAK"


@contextmanager
def openai_server(answers: list):
    """A local OpenAI-compatible chat-completions endpoint with scripted answers."""
    seen = []

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self):
            body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
            seen.append((self.path, dict(self.headers), body))
            status, text = answers.pop(0) if answers else (200, "{}")
            payload = {"id": "x", "object": "chat.completion", "created": 0, "model": body["model"],
                       "choices": [{"index": 0, "finish_reason": "stop",
                                    "message": {"role": "assistant", "content": text}}],
                       "usage": {"prompt_tokens": 10, "completion_tokens": 5, "total_tokens": 15}}
            data = json.dumps(payload if status == 200 else {"error": {"message": f"nope {KEY}"}}).encode()
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def log_message(self, *a):
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}/v1", seen
    finally:
        httpd.shutdown()
        httpd.server_close()


def test_vlm_planner_against_a_local_openai_compatible_server(obs):
    first = json.dumps({"plans": ["pick up the book", "place it in the caddy"], "done": [], "now": "pick up the book"})
    second = "```json\n" + json.dumps({"plans": ["pick up the book", "place it in the caddy"],
                                       "done": ["pick up the book"], "now": "place it in the caddy"}) + "\n```"
    with openai_server([(200, first), (200, second), (200, "I think you should pick it up"), (401, "")]) as (url, seen):
        planner = VLMPlanner("planner-model", url, api_key=KEY, timeout_s=5, max_retries=0)
        planner.reset(BOOK.instruction)
        assert planner.next(obs) == Reasoning(("pick up the book", "place it in the caddy"), (), "pick up the book")
        r = planner.next(obs)
        assert r.done == ("pick up the book",) and r.now == "place it in the caddy"
        path, headers, body = seen[0]
        assert path == "/v1/chat/completions" and body["model"] == "planner-model"
        text, image = body["messages"][0]["content"]
        assert BOOK.instruction in text["text"] and image["image_url"]["url"].startswith("data:image/png;base64,")
        assert "already attempted" in seen[1][2]["messages"][0]["content"][0]["text"]
        with pytest.raises(PlannerError, match="not a JSON object"):
            planner.next(obs)
        with pytest.raises(PlannerError) as err:
            planner.next(obs)
        assert KEY not in str(err.value) and "401" in str(err.value)
    with pytest.raises(PlannerError, match="'now' 'fly' is not one of its plans"):
        parse_plan_answer('{"plans": ["walk"], "done": [], "now": "fly"}')


# ---------------------------------------------------------------------------- servers that misbehave


@contextmanager
def rogue_server(on_request, metadata=None):
    """A real websocket server whose answers a test scripts: ``on_request(ws, request, state)``
    returns bytes/str to send, None to send nothing, or "close" to drop the connection.
    ``state["seen"]`` holds every request; anything ``on_request`` raises (a failed assertion
    about a request) is re-raised when the block exits, so it fails the test."""
    state = {"connections": 0, "requests": 0, "seen": [], "errors": [], "release": threading.Event()}

    def handler(ws):
        state["connections"] += 1
        try:
            ws.send(msgpack_numpy.packb({} if metadata is None else metadata))
            for message in ws:
                state["requests"] += 1
                request = msgpack_numpy.unpackb(message)
                state["seen"].append(request)
                out = on_request(ws, request, state)
                if out == "close":
                    ws.close()
                    return
                if out is not None:
                    ws.send(out)
        except ConnectionClosed:  # the client went away; nothing to do
            pass
        except BaseException as exc:  # noqa: BLE001 - kept for the test thread, which re-raises it
            state["errors"].append(exc)

    server = ws_sync_server.serve(handler, "127.0.0.1", 0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.socket.getsockname()[1], state, server
    finally:
        state["release"].set()
        server.shutdown()
        thread.join(5)
    if state["errors"]:
        raise state["errors"][0]


def _plain_client(port, **kw) -> OpenpiPolicy:
    return OpenpiPolicy(ClientConfig(port=port, **{**FAST, **kw}), planner=AnnotationPlanner(["pick up the book"]))


GOOD = msgpack_numpy.packb({"actions": np.zeros((10, 7), np.float32)})


@pytest.mark.parametrize("reply, message", [
    (msgpack_numpy.packb({"action": np.zeros((10, 7))}), r"missing key 'actions'; got keys \['action'\]"),
    (msgpack_numpy.packb({"actions": np.zeros((10, 6))}), r"expected .*\('H', 7\) with H >= 5, got shape \(10, 6\)"),
    (msgpack_numpy.packb({"actions": np.zeros((3, 7))}), r"got shape \(3, 7\)"),
    (msgpack_numpy.packb({"actions": [[0.0] * 7] * 10}), "expected a float array.*got list"),
    (msgpack_numpy.packb({"actions": np.full((10, 7), np.nan)}), "NaN or Inf"),
    (msgpack_numpy.packb({"actions": np.zeros((10, 7)), "think": "yes"}), "'think': expected bool"),
    (b"\xc1\xc1 not msgpack", "not valid msgpack-numpy"),
    ("Traceback: model exploded", "answered with an error: Traceback: model exploded"),
])
def test_malformed_replies_are_named(obs, reply, message):
    with rogue_server(lambda ws, req, st: reply) as (port, state, _):
        with _plain_client(port) as policy:
            r = policy.reason(obs)
            with pytest.raises(P.PolicyServerError, match=message):
                policy.act([obs], r)
    # One request, carrying openpi's four LIBERO keys and nothing of SEAL's (this server announced
    # no SEAL extension, so the client must speak plain openpi to it).
    assert [sorted(req) for req in state["seen"]] == [sorted([P.IMAGE, P.WRIST, P.STATE, P.PROMPT])]
    with rogue_server(lambda ws, req, st: GOOD) as (port, state, _):
        with _plain_client(port) as policy:
            assert policy.act([obs], policy.reason(obs))[0].actions.shape == (10, 7)


def test_malformed_metadata_is_named():
    with rogue_server(lambda *a: GOOD, metadata={"seal": {"batch": "yes"}}) as (port, _, _):
        with pytest.raises(P.ProtocolError, match="seal.batch must be bool, got 'yes'"):
            _plain_client(port)


def test_dropped_connection_is_reopened_and_a_dead_server_is_a_clear_error(obs):
    def drop_every_third(ws, req, state):
        assert set(req) == {P.IMAGE, P.WRIST, P.STATE, P.PROMPT}
        return "close" if state["requests"] % 3 == 0 else GOOD

    with rogue_server(drop_every_third) as (port, state, server):
        with _plain_client(port, transport="sequential") as policy:
            r = policy.reason(obs)
            chunks = policy.act([obs] * 6, r)  # requests 3 and 6 are dropped, then resent
            assert len(chunks) == 6 and state["connections"] == 3
            server.shutdown()  # the server goes away mid-episode
            t0 = time.perf_counter()
            with pytest.raises(P.PolicyServerError, match=r"cannot reach the policy server at ws://127.0.0.1:\d+"):
                policy.act([obs] * 3, r)
            assert time.perf_counter() - t0 < 8


def test_seal_serve_stopping_mid_episode_ends_the_run_with_a_clear_error(pool):
    # The server is stopped from inside the episode, at its second batch of candidates, so the
    # test does not depend on how fast this machine plays an episode (a timer did: a fast machine
    # finished the whole episode before the timer fired).
    class StopsServerOnSecondAct(OpenpiPolicy):
        calls = 0

        def act(self, obs_batch, reasoning, **kw):
            StopsServerOnSecondAct.calls += 1
            if StopsServerOnSecondAct.calls == 2:
                srv.stop()
            return super().act(obs_batch, reasoning, **kw)

    with ServerThread(_scripted()) as srv:
        policy = StopsServerOnSecondAct(ClientConfig(port=srv.port, **FAST), task=BOOK.key)
        t0 = time.perf_counter()
        with pytest.raises(P.PolicyServerError, match="cannot reach the policy server"):
            Steerer(pool, policy, OracleVerifier(), SteerConfig(method="seal", k=4)).run(0)
        assert StopsServerOnSecondAct.calls == 2
        assert time.perf_counter() - t0 < 20
        policy.close()


def test_silent_server_times_out_instead_of_hanging(obs):
    def never(ws, req, state):
        state["release"].wait(30)
        return None

    with rogue_server(never) as (port, _, _):
        with _plain_client(port, request_timeout_s=0.5, transport="concurrent") as policy:
            r = policy.reason(obs)
            t0 = time.perf_counter()
            with pytest.raises(P.PolicyServerError, match=r"no reply from the policy server .* within 0.5 s"):
                policy.act([obs] * 3, r)
            assert time.perf_counter() - t0 < 5


def test_unreachable_server_fails_after_retries_with_backoff():
    import socket

    with socket.socket() as s:  # a port that nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    with pytest.raises(P.PolicyServerError, match=r"ws://127.0.0.1:\d+: 3 attempt\(s\)"):
        OpenpiPolicy(ClientConfig(port=port, connect_timeout_s=1, connect_retries=2, backoff_s=0.2),
                     planner=AnnotationPlanner(["x"]))
    assert 0.6 - 0.05 <= time.perf_counter() - t0 < 5  # backoff 0.2 + 0.4 s


def test_bad_client_and_engine_settings():
    with pytest.raises(InvalidInput, match="valid: auto, batched, concurrent, sequential"):
        ClientConfig(transport="pigeon")
    with pytest.raises(InvalidInput, match="check_every >= 5"):
        SteerConfig(check_every=1)


# ---------------------------------------------------------------------------- the server enforces what it advertises


def _configured_lane(port: int, max_batch: int = 64) -> _Lane:
    lane = _Lane(ClientConfig(port=port, **FAST))
    assert lane.connect()["seal"]["max_batch"] == max_batch  # what it advertises
    assert lane.call({P.CONTROL: "configure", "task": BOOK.key})["ok"] is True
    return lane


def _scene_batch(lane: _Lane, obs, n: int, *, reason: bool = True) -> dict:
    """n rows of the book task's first observation as one batched request (no cameras: the
    scripted expert reads the scene), after the server reasoned and began n attempts."""
    one = {k: v for k, v in P.observation_request(obs, info=P.ServerInfo(privileged=True)).items()
           if k not in (P.IMAGE, P.WRIST)}
    if not reason:
        return P.batch_request([one] * n)
    reasoning = lane.call(one)[P.REASONING]
    assert lane.call({P.CONTROL: "begin", "k": n})["ok"] is True
    return dict(P.batch_request([one] * n), **{P.REASONING: reasoning})


def test_server_refuses_batches_larger_than_its_max_batch(obs):
    with ServerThread(_scripted()) as srv:  # advertises max_batch 64
        lane = _configured_lane(srv.port)
        said = lane.call(_scene_batch(lane, obs, 500))
        assert isinstance(said, str) and "'seal/batch': 500 observations, but this server takes at most 64" in said
        ok = lane.call(_scene_batch(lane, obs, 2))
        assert not isinstance(ok, str), ok
        assert ok["actions"].shape == (2, 16, 7)  # the same connection still works
        lane.close()
    with ServerThread(_scripted(max_batch=4)) as srv:
        lane = _configured_lane(srv.port, max_batch=4)
        assert "5 observations, but this server takes at most 4" in lane.call(_scene_batch(lane, obs, 5))
        assert lane.call(_scene_batch(lane, obs, 4))["actions"].shape == (4, 16, 7)
        lane.close()
    with ServerThread(_scripted(plain=True)) as srv:  # seal.batch false: no batched requests at all
        lane = _configured_lane(srv.port)
        assert "does not take batched requests" in lane.call(_scene_batch(lane, obs, 2, reason=False))
        lane.close()


def test_server_refuses_non_finite_inputs(obs):
    with ServerThread(_scripted()) as srv:
        lane = _configured_lane(srv.port)
        req = P.observation_request(obs, info=P.ServerInfo(privileged=True))
        state = req[P.STATE].copy()
        state[3] = np.nan
        said = lane.call(dict(req, **{P.STATE: state}))
        assert isinstance(said, str) and "'observation/state': contains NaN or Inf; expected finite floats" in said
        batch = _scene_batch(lane, obs, 3)
        batch[P.STATE] = batch[P.STATE].copy()
        batch[P.STATE][1, 0] = np.inf
        assert "contains NaN or Inf (rows [1])" in lane.call(batch)
        scene = P.scene_to_wire(obs.scene)
        scene["eef_pos"] = np.array([0.0, np.nan, 0.0])
        assert "seal/scene eef_pos: contains NaN or Inf" in lane.call(dict(req, **{P.SCENE: scene}))
        scene = P.scene_to_wire(obs.scene)
        scene["table_z"] = float("inf")
        assert "seal/scene table_z: contains NaN or Inf" in lane.call(dict(req, **{P.SCENE: scene}))
        assert lane.call(req)["actions"].shape == (16, 7)  # the same connection still works
        lane.close()


class _NaNPolicy:
    """A policy that breaks on some inputs: rows whose state starts above 0.5 get NaN actions."""

    thinks = False

    def reset(self, instruction, seed=0):
        pass

    def begin(self, k):
        pass

    def reason(self, obs):
        return Reasoning(("act",), (), "act")

    def act(self, obs_batch, reasoning, rows=None):
        from seal.policies.base import ActionChunk

        return [ActionChunk(np.full((16, 7), np.nan if o.state[0] > 0.5 else 0.0)) for o in obs_batch]


def test_server_never_sends_non_finite_actions():
    info = P.ServerInfo(batch=True, max_batch=4, control=True, images=False, version=P.PROTOCOL_VERSION)
    with ServerThread(PolicyServer(lambda task: _NaNPolicy(), info, default_task=BOOK.key)) as srv:
        lane = _Lane(ClientConfig(port=srv.port, **FAST))
        lane.connect()
        states = np.zeros((3, 8), np.float32)
        states[1, 0] = 1.0
        said = lane.call({P.BATCH: 3, P.STATE: states, P.PROMPT: "go"})
        assert isinstance(said, str) and said.startswith("PolicyServerError: the policy produced NaN or Inf actions "
                                                         "for rows [1]; none are sent")
        assert "produced NaN or Inf actions;" in lane.call({P.STATE: states[1], P.PROMPT: "go"})
        reply = lane.call({P.STATE: states[0], P.PROMPT: "go"})  # the same connection still works
        assert reply["actions"].shape == (16, 7) and np.all(reply["actions"] == 0)
        lane.close()


def test_configure_refuses_unknown_tasks_naming_the_valid_ones():
    with ServerThread(_scripted()) as srv:
        lane = _Lane(ClientConfig(port=srv.port, **FAST))
        lane.connect()
        said = lane.call({P.CONTROL: "configure", "task": "pick up the book"})
        assert isinstance(said, str) and said.startswith("InvalidInput: unknown task 'pick up the book'; valid: "
                                                         "SUITE/ID")
        assert "libero_10, libero_90, lang_rephrase" in said
        assert "unknown task 'libero_99/0'; valid: SUITE/ID" in lane.call({P.CONTROL: "configure",
                                                                            "task": "libero_99/0"})
        assert "valid ids: 0..9" in lane.call({P.CONTROL: "configure", "task": "libero_10/10"})
        assert lane.call({P.CONTROL: "configure", "task": BOOK.key})["ok"] is True  # still open
        lane.close()
    with pytest.raises(InvalidInput, match="unknown task 'libero_10/99'.*valid ids: 0..9"):
        PolicyServer(scripted_factory(), scripted_info(), default_task="libero_10/99")


def test_seal_serve_refuses_an_unknown_default_task_before_listening(capsys):
    from seal.cli import main

    assert main(["serve", "--task", "libero_10/99", "--port", "0"]) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == ["seal: error: unknown task 'libero_10/99': unknown task id 99 for suite "
                                         "'libero_10'; valid ids: 0..9"]
    assert "listening" not in captured.out


def test_seal_serve_refuses_a_bad_or_busy_port_in_one_line(capsys):
    import socket

    from seal.cli import main

    for port in ("70000", "-1"):
        assert main(["serve", "--port", port]) == 2
        err = capsys.readouterr().err
        assert err.splitlines() == [f"seal: error: port must be in 1..65535 (or 0: any free port), got {port}"]
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        assert main(["serve", "--port", str(port)]) == 2
        captured = capsys.readouterr()
        assert captured.err.splitlines() == [f"seal: error: cannot listen on 127.0.0.1:{port}: port {port} is already "
                                             "in use (another server?); choose another port, or 0 for any free one"]
        assert "listening" not in captured.out
        t0 = time.perf_counter()
        with pytest.raises(InvalidInput, match=f"port {port} is already in use"):
            with ServerThread(PolicyServer(scripted_factory(), scripted_info(), port=port)):
                pass
        assert time.perf_counter() - t0 < 10  # the thread reports it at once, not after its 30 s start timeout
    with pytest.raises(InvalidInput, match="got 70000"):
        PolicyServer(scripted_factory(), scripted_info(), port=70000)
