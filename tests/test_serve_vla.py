"""`seal serve --policy vla`: a learned VLA checkpoint behind openpi's protocol, and the VLA on the
V-GPS baseline path (`method value`). Tiny random checkpoints, one thread."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from openpi_client import msgpack_numpy

from seal.cli import main
from seal.errors import InvalidInput
from seal.policies import make_policy
from seal.policies.base import Reasoning, parse_reasoning
from seal.policies.planners import AnnotationPlanner
from seal.policies.vla.checkpoint import save_checkpoint
from seal.policies.vla.model import VLAConfig, VLAModel
from seal.policies.vla.policy import VLAPolicy
from seal.policies.vla.tokenizer import VLATokenizer, project_texts, train_tokenizer
from seal.serving import protocol as P
from seal.serving.client import ClientConfig, OpenpiPolicy, _Lane
from seal.serving.server import PolicyServer, ServerProcess, ServerThread, vla_factory, vla_info
from seal.sim.observation import Observation
from seal.sim.suites import get_task
from seal.steer.method import MethodSpec

torch.set_num_threads(1)

BOOK = get_task("libero_10", 5)  # two sub-plans: the quickest LIBERO-10 task
FAST = dict(connect_timeout_s=5.0, connect_retries=1, backoff_s=0.05, request_timeout_s=30.0)
SIZE = 32  # the tiny models' camera size (a real one is trained at 64)


def _tiny(tok: VLATokenizer, **kw) -> VLAConfig:
    return VLAConfig(**{**dict(vocab_size=tok.vocab_size, image_size=SIZE, patch=8, d_model=32, n_heads=2, n_layers=2,
                               d_expert=32, expert_heads=2, expert_layers=2, mlp_ratio=2, max_instruction_tokens=16,
                               max_reasoning_tokens=112), **kw})


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("vla_ckpts")
    tok = train_tokenizer(project_texts() + [BOOK.instruction], vocab_size=400)
    torch.manual_seed(0)
    return {"reason": save_checkpoint(root / "reason", VLAModel(_tiny(tok)), tok),
            "twin": save_checkpoint(root / "twin", VLAModel(_tiny(tok, reasoning=False)), tok)}


def _obs(size: int, seed: int = 0) -> Observation:
    rng = np.random.default_rng(seed)
    return Observation(state=rng.normal(size=8), prompt=BOOK.instruction,
                       agent=rng.integers(0, 256, (size, size, 3), dtype=np.uint8),
                       wrist=rng.integers(0, 256, (size, size, 3), dtype=np.uint8))


def _chunks(chunks) -> np.ndarray:
    return np.stack([c.actions for c in chunks]).astype(np.float32)


# ---------------------------------------------------------------------------- seal serve --policy vla


def test_seal_serve_vla_process_answers_the_remote_client_like_the_policy_in_process(ckpts):
    """A real `seal serve --policy vla:PATH` child process and the `remote` policy client: K chunks
    per batched request, the reasoning text over the wire, 224-px frames resized as in-process."""
    k, big = 5, _obs(224)  # an openpi client's frames
    local = VLAPolicy.load(ckpts["reason"], seed=0)
    local.reset(BOOK.instruction, seed=3)
    want_r = local.reason(big)
    local.begin(1)  # the server answers a reasoning request with a first chunk as well
    local.act([big], want_r, rows=[0])
    local.begin(k)
    want = _chunks(local.act([big] * k, want_r))
    with ServerProcess(["--policy", f"vla:{ckpts['reason']}", "--max-batch", "8"]) as server:
        spec = MethodSpec(policy="remote", port=server.port)
        policy = make_policy("remote", spec, BOOK, seed=0)
        with policy:
            assert policy.info == P.ServerInfo(reasoning=True, batch=True, max_batch=8, control=True, images=True,
                                               image_size=SIZE, version=P.PROTOCOL_VERSION,
                                               max_request_bytes=P.request_limit(8, SIZE))
            assert policy.metadata["policy"] == "vla" and policy.metadata["checkpoint"] == str(ckpts["reason"])
            assert policy.transport == "batched" and policy.thinks and policy.privileged_atoms() is None
            assert policy.image_size == SIZE  # the steering loop renders the cameras at the model's size
            policy.reset(BOOK.instruction, seed=3)
            reasoning = policy.reason(big)  # parsed from the reply's text (strict parser)
            assert reasoning == want_r and parse_reasoning(reasoning.text()) == reasoning
            policy.begin(k)
            chunks = policy.act([big] * k, reasoning)
            got = _chunks(chunks)
            assert got.shape == (k, 16, 7) and np.abs(got).max() <= 1.0
            assert all(isinstance(c.think, bool) for c in chunks)
            assert not np.allclose(got[0], got[1])  # one shared prefix, own noise per row
            np.testing.assert_allclose(got, want, atol=1e-6)
            assert policy.requests == 2  # one reasoning request, one batched request of K
            # frames already at the advertised size are taken as they are
            small = policy.act([_obs(SIZE, 1), _obs(SIZE, 2)], reasoning, rows=[1, 4])
            assert _chunks(small).shape == (2, 16, 7)
        assert server.stop() == 0
        last = json.loads(server.proc.stdout.read().strip().splitlines()[-1])
        assert last == {"event": "stopped", "requests": last["requests"]} and last["requests"] >= 6


def test_twin_and_plain_vla_servers_answer_like_pi0(ckpts):
    """The twin cannot reason: its server says so, a client brings a planner, and K rows still go
    in one batched request. A plain openpi client (no configure, 224-px frames) is served too."""
    from openpi_client.websocket_client_policy import WebsocketClientPolicy

    obs, k = _obs(224), 3
    twin = vla_factory(str(ckpts["twin"]))
    local = VLAPolicy.load(ckpts["twin"])
    local.reset(BOOK.instruction, seed=5)
    local.begin(k)
    want = _chunks(local.act([obs] * k, local.reason(obs)))
    with ServerThread(PolicyServer(twin, vla_info(twin), default_task="")) as srv:
        cfg = ClientConfig(port=srv.port, **FAST)
        with pytest.raises(InvalidInput, match="does not return reasoning.*give a planner"):
            OpenpiPolicy(cfg, task=BOOK.key)
        planner = AnnotationPlanner(["pick up the book"])
        with OpenpiPolicy(cfg, task=BOOK.key, planner=planner) as policy:
            assert not policy.thinks and policy.transport == "batched" and policy.image_size == SIZE
            policy.reset(BOOK.instruction, seed=5)
            reasoning = policy.reason(obs)
            assert reasoning == Reasoning(("pick up the book",), (), "pick up the book")
            policy.begin(k)
            chunks = policy.act([obs] * k, reasoning)
            np.testing.assert_allclose(_chunks(chunks), want, atol=1e-6)
            assert policy.requests == 1 and not any(c.think for c in chunks)
        client = WebsocketClientPolicy(host="127.0.0.1", port=srv.port)  # openpi's own client, no configure
        assert client.get_server_metadata()["seal"]["image_size"] == SIZE
        reply = client.infer(P.observation_request(obs, info=P.ServerInfo()))
        assert reply["actions"].shape == (16, 7) and "reasoning" not in reply and "think" not in reply
        client._ws.close()
        lane = _Lane(cfg)
        lane.connect()
        bad = dict(P.observation_request(obs, info=P.ServerInfo()), **{P.IMAGE: np.zeros((100, 100, 3), np.uint8)})
        assert "expected uint8 array of shape (224, 224, 3) or (32, 32, 3), got uint8 (100, 100, 3)" in lane.call(bad)
        assert lane.call(P.observation_request(obs, info=P.ServerInfo()))["actions"].shape == (16, 7)  # still open
        lane.close()
    reason = vla_factory(str(ckpts["reason"]))
    with ServerThread(PolicyServer(reason, vla_info(reason, plain=True), default_task="")) as srv:
        client = WebsocketClientPolicy(host="127.0.0.1", port=srv.port)
        assert client.get_server_metadata()["seal"]["reasoning"] is False
        reply = client.infer(P.observation_request(obs, info=P.ServerInfo()))
        assert reply["actions"].shape == (16, 7) and "reasoning" not in reply and "think" not in reply
        client._ws.close()


def test_seal_serve_refuses_bad_policies_before_listening(tmp_path, capsys):
    assert main(["serve", "--policy", f"vla:{tmp_path / 'nowhere'}", "--port", "0"]) == 2
    assert "no VLA checkpoint at" in capsys.readouterr().err
    assert main(["serve", "--policy", "remote", "--port", "0"]) == 2
    assert "valid: scripted, vla, vla:PATH" in capsys.readouterr().err
    with pytest.raises(P.ProtocolError, match="image_size must be in 16..1024"):
        P.ServerInfo.from_metadata({"seal": {"image_size": 4}})
    assert msgpack_numpy  # the wire codec the server uses is importable here too


# ---------------------------------------------------------------------------- the V-GPS baseline path


@pytest.mark.parametrize("value_size", [224, SIZE])
def test_value_method_with_the_vla_twin(ckpts, tmp_path, value_size):
    """Twin + V-GPS: the twin reads its cameras at its own size, the Q-function scores the view it was
    trained on (openpi's 224 px, or the twin's own size when trained on the twin's data), and each
    executed chunk is the best-scored one."""
    from test_train_value import _bandit

    from seal.steer.build import build_episode
    from seal.train.vgps import IQLConfig, train_value
    from seal.value.vgps import VGPSScorer

    torch.manual_seed(0)
    train_value(_bandit(64, 0), tmp_path / "vgps", IQLConfig(steps=2, batch_size=16, hidden=16), image_size=value_size)
    spec = MethodSpec(method="value", k=3, policy=f"vla:{ckpts['twin']}", value_ckpt=str(tmp_path / "vgps"))
    seen: dict[str, list] = {"policy": [], "scorer": []}

    class Scorer(VGPSScorer):
        def score(self, obs, chunks, goal):
            scores = super().score(obs, chunks, goal)
            seen["scorer"].append((obs.agent.shape, chunks.copy(), scores))
            return scores

    policy = make_policy(spec.policy, spec, BOOK, seed=0)
    assert not policy.thinks
    act = policy.act
    policy.act = lambda obs_batch, reasoning, rows=None: (
        seen["policy"].extend(o.agent.shape for o in obs_batch) or act(obs_batch, reasoning, rows))
    scorer = Scorer.load(tmp_path / "vgps")
    with build_episode(spec, BOOK, seed=0, max_steps=15, policy=policy, scorer=scorer, workers=1) as episode:
        result = episode.run(0)
    assert result.steps == 15 and not result.sim_error
    assert result.aligned == [None]  # the twin's one "sub-plan" is the task: not an alignment audit
    assert set(seen["policy"]) == {(SIZE, SIZE, 3)}  # rendered at the model's size
    assert len(seen["scorer"]) == 3 and {s for s, _, _ in seen["scorer"]} == {(value_size, value_size, 3)}
    executed = np.asarray(result.executed_actions)
    for i, (_, chunks, scores) in enumerate(seen["scorer"]):
        assert chunks.shape == (3, 16, 7)
        np.testing.assert_array_equal(executed[5 * i: 5 * i + 5], np.clip(chunks[int(np.argmax(scores))][:5], -1, 1))


# ---------------------------------------------------------------------------- the server enforces its metadata


def _vla_lane(port: int) -> _Lane:
    lane = _Lane(ClientConfig(port=port, **FAST))
    lane.connect()
    return lane


def _batch(n: int, size: int = SIZE) -> dict:
    req = P.batch_request([P.observation_request(_obs(size, i), info=P.ServerInfo()) for i in range(n)])
    req[P.REASONING] = Reasoning(("pick up the book",), (), "pick up the book").text()
    return req


def test_vla_server_refuses_batches_larger_than_its_max_batch(ckpts):
    reason = vla_factory(str(ckpts["reason"]))
    with ServerThread(PolicyServer(reason, vla_info(reason), default_task="")) as srv:  # max_batch 64
        lane = _vla_lane(srv.port)
        said = lane.call(_batch(500))
        assert isinstance(said, str) and "500 observations, but this server takes at most 64 per request" in said
        assert lane.call(_batch(3))["actions"].shape == (3, 16, 7)  # the same connection still works
        lane.close()


def test_vla_server_refuses_a_non_finite_state_instead_of_answering_nan_actions(ckpts):
    reason = vla_factory(str(ckpts["reason"]))
    with ServerThread(PolicyServer(reason, vla_info(reason), default_task="")) as srv:
        lane = _vla_lane(srv.port)
        req = P.observation_request(_obs(SIZE), info=P.ServerInfo())
        for bad in (np.nan, np.inf, -np.inf):
            state = req[P.STATE].copy()
            state[0] = bad
            said = lane.call(dict(req, **{P.STATE: state}))
            assert isinstance(said, str) and "'observation/state': contains NaN or Inf; expected finite floats" in said
        reply = lane.call(req)  # the same connection still works
        assert np.all(np.isfinite(reply["actions"]))
        lane.close()


def test_vla_server_refuses_configure_with_an_unknown_task(ckpts):
    reason = vla_factory(str(ckpts["reason"]))
    with ServerThread(PolicyServer(reason, vla_info(reason), default_task="")) as srv:
        lane = _vla_lane(srv.port)
        said = lane.call({P.CONTROL: "configure", "task": "libero_10/99"})
        assert isinstance(said, str) and "unknown task 'libero_10/99'" in said and "valid ids: 0..9" in said
        assert "SUITE/ID, e.g. 'libero_10/0', with SUITE one of libero_10" in lane.call(
            {P.CONTROL: "configure", "task": "book"})
        assert lane.call({P.CONTROL: "configure", "task": BOOK.key})["ok"] is True  # still open; known tasks work
        lane.close()
        with pytest.raises(P.PolicyServerError, match="refused 'configure'.*unknown task 'libero_10/99'"):
            OpenpiPolicy(ClientConfig(port=srv.port, **FAST), task="libero_10/99")


def test_vla_server_bounds_frames_and_request_size(ckpts):
    """Frames are uint8 (224, 224, 3) or (image_size, image_size, 3), both cameras; a
    request over the advertised max_request_bytes closes its connection (1009), naming the limit,
    and the server keeps serving."""
    reason = vla_factory(str(ckpts["reason"]))
    with ServerThread(PolicyServer(reason, vla_info(reason, max_batch=2), default_task="")) as srv:
        lane = _Lane(ClientConfig(port=srv.port, **FAST))
        limit = lane.connect()["seal"]["max_request_bytes"]
        assert limit == P.request_limit(2, SIZE) == (1 << 20) + 2 * (2 * 224 * 224 * 3 + (1 << 20))
        req = P.observation_request(_obs(SIZE), info=P.ServerInfo())
        for image in (np.zeros((512, 512, 3), np.uint8), np.zeros((SIZE, SIZE, 4), np.uint8),
                      np.zeros((SIZE, SIZE, 3), np.float32), np.zeros((2, SIZE, SIZE, 3), np.uint8)):
            said = lane.call(dict(req, **{P.IMAGE: image}))
            assert isinstance(said, str) and "expected uint8 array of shape (224, 224, 3) or (32, 32, 3)" in said
        assert "missing keys ['observation/image']" in lane.call({k: v for k, v in req.items() if k != P.IMAGE})
        with pytest.raises(P.PolicyServerError, match=rf"1009 \(message too big\).*exceeds limit of {limit} bytes"):
            lane.call(dict(req, junk=np.zeros(limit, np.uint8)))  # over the limit: the server does not read it
        lane.close()
        lane = _vla_lane(srv.port)  # the server is still up
        assert lane.call(req)["actions"].shape == (16, 7)
        lane.close()
