"""A policy plug-in from outside the package (issue 35): its options dataclass and its factory live
here, one registry line adds it, and the method description, the episode builder and the CLI's
generated flags take it in with no other file touched."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from seal.options import Options, option, real_in
from seal.policies import POLICIES
from seal.policies.base import ActionChunk
from seal.sim.suites import get_task
from seal.steer.build import build_episode
from seal.steer.method import MethodSpec, parse_methods
from seal.steer.trace import read_trace

BOOK = get_task("libero_10", 5)  # two sub-plans, ~90 steps: the quickest LIBERO-10 task
SHORT = 40  # control steps: a sub-plan round with K=2


@dataclass(frozen=True)
class GentleOptions(Options):
    scale: float = option(1.0, "gentle policy: factor on the expert's actions", type=real_in(0.0, 1.0, low_open=True))


class GentleExpert:
    """The scripted expert with its actions scaled down: a made-up policy that needs one option."""

    def __init__(self, inner, scale: float):
        self._inner, self.scale = inner, scale
        self.thinks = inner.thinks

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def act(self, obs_batch, reasoning, rows=None):
        chunks = self._inner.act(obs_batch, reasoning, rows)
        return [ActionChunk(np.clip(c.actions, -1.0, 1.0) * self.scale, c.think) for c in chunks]


BUILT: list[GentleOptions] = []


def gentle_policy(options: GentleOptions, task, *, seed: int = 0) -> GentleExpert:
    from seal.policies.expert.policy import FailureKnobs, ScriptedExpert

    BUILT.append(options)
    return GentleExpert(ScriptedExpert.for_task(task, FailureKnobs.misaligned(), seed=seed), options.scale)


@pytest.fixture
def gentle():
    POLICIES.register("gentle", gentle_policy, GentleOptions, "the scripted expert, its actions scaled (--scale)")
    BUILT.clear()
    yield
    POLICIES.unregister("gentle")


def test_a_policy_plugin_is_its_module_and_one_registry_line(gentle, tmp_path):
    spec = MethodSpec(method="seal", k=2, policy="gentle", scale=0.8)
    assert spec.policy_options == GentleOptions(scale=0.8) and spec.scale == 0.8
    assert spec.canonical()["policy"] == "gentle" and spec.canonical()["scale"] == 0.8 and "knobs" not in spec.canonical()
    assert spec.label == "seal[k=2,policy=gentle,scale=0.8]"
    assert parse_methods("seal:k=2:policy=gentle:scale=0.8") == [spec]
    assert MethodSpec(method="seal", k=2, policy="gentle").config_hash != spec.config_hash

    # the normal build path runs a short SEAL episode with it
    with build_episode(spec, BOOK, seed=0, out_dir=tmp_path, max_steps=SHORT, grids=False, workers=2) as episode:
        result = episode.run(0)
    assert BUILT == [GentleOptions(scale=0.8)]
    assert result.steps > 0 and result.verifier_calls > 0 and not result.sim_error
    executed = np.abs(np.asarray(result.executed_actions))
    assert executed.max() <= 0.8 + 1e-6  # every executed action went through the plug-in
    assert any(e["event"] == "commit" for e in read_trace(tmp_path / "trace.jsonl"))

    # the CLI's method options are generated from the registries: the new flag and name are there
    from seal.cli import build_parser

    parser = build_parser()
    sub = parser._subparsers._group_actions[0].choices
    for command in ("run", "eval"):
        flags = {o: a for a in sub[command]._actions for o in a.option_strings}
        assert "--scale" in flags and "factor on the expert's actions (default 1.0)" in flags["--scale"].help
        assert "gentle: the scripted expert, its actions scaled" in flags["--policy"].help
    args = parser.parse_args(["run", "--policy", "gentle", "--scale", "0.8", "--k", "2"])
    assert (args.policy, args.scale) == ("gentle", 0.8)
    with pytest.raises(SystemExit):
        parser.parse_args(["run", "--scale", "3"])  # its declared type checks the flag


def test_an_unregistered_plugin_is_gone(gentle):
    POLICIES.unregister("gentle")
    from seal.errors import InvalidInput

    with pytest.raises(InvalidInput, match="unknown policy 'gentle'; valid: scripted, remote, vla"):
        MethodSpec(policy="gentle")


def test_seal_serve_and_bench_runtime_take_a_registered_policy(gentle):
    from seal.benchmarks.steer import runtime_policies
    from seal.errors import InvalidInput
    from seal.policies import servable
    from seal.serving.server import policy_server

    assert "gentle" in servable() and "gentle" in runtime_policies() and "remote" not in servable()
    factory, info, meta, default_task = policy_server("gentle", GentleOptions(scale=0.5), task=BOOK.key)
    assert meta["policy"] == "gentle" and default_task == BOOK.key
    assert info.reasoning and info.privileged and not info.images  # what the wrapped expert is
    policy = factory(BOOK.key)
    assert isinstance(policy, GentleExpert) and policy.scale == 0.5
    policy.close()
    with pytest.raises(InvalidInput, match="give --task"):
        policy_server("gentle", GentleOptions(), task="")
