"""One description of a steering method: `MethodSpec`.

`seal run`, `seal eval`, the benchmarks and the Ray backend all describe what they run with this
one dataclass: the method (base, random, value, seal), K, rounds, the verifier and its options,
the policy and its options, sync/replay mode, the prediction physics' mismatch, the render model
and the loop's budgets. `build_episode` (`seal.steer.build`) turns it into a running episode.

Its canonical form (what changes results) is hashed to name the method in a results store. The
hash must stay what older stores hold, so the rule for a field added later is: it enters the
canonical form only when it differs from its default (an old configuration, which could only
have the default, hashes as before). Connection details (host, port, URLs, timeouts, transport)
never enter it: they say where a model runs, not what it is. A learned policy's checkpoint
(``policy_ckpt``, also written ``policy="vla:PATH"``) enters it as the digest of its weights, as
``value_ckpt`` does, so retraining in place is a new method.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from seal.errors import InvalidInput
from seal.steer.selection import METHODS, SELECTIONS  # one per candidate-selection object

KNOBS = ("clean", "misaligned")
MODES = ("sync", "replay")
VALUE_GOALS = ("task", "subplan")
PICKS = ("first", "best")  # seal: the first candidate to pass, or the most confident pass of a whole round
# seal: in which order verdicts are taken. "slot": at each chunk boundary the loop waits for the verdicts of
# the candidates that ended there and takes them candidate 0 first (the trace is a function of the seeds);
# "arrival": as they come in from the background verifier while sampling goes on (thread timing decides ties)
VERIFY_ORDERS = ("slot", "arrival")
# seal: what happens when the policy writes that the task is complete. "verify": the verifier is asked whether
# the instruction holds, and a refusal sends the policy back to its last claimed sub-plan; "trust": the episode
# ends on the policy's word (every result stored before the check existed)
DONE_CHECKS = ("verify", "trust")
RENDERS = ("stock", "fast")
PLANNERS = ("", "annotations", "vlm")
PROMPTS = ("task", "subplan")
TRANSPORTS = ("auto", "batched", "concurrent", "sequential")

# Fields added after stores existed: in the canonical form only when not at their default.
_LATER = ("mismatch", "check_every", "subplan_budget", "planner", "annotations", "planner_model", "prompt",
          "policy_ckpt", "pick", "verify_order")
# Fields whose default changed behaviour when they were added: in the canonical form only when not at the
# value every earlier result ran with, so stored results keep their hashes and new ones get new hashes.
_LEGACY = {"done_check": "trust"}
_NO_HASH = {"hash": False}  # where a model runs, not what it is


@dataclass(frozen=True)
class MethodSpec:
    """A steering method and every setting that changes its results (plus where its models run)."""

    method: str = "seal"
    k: int = 10
    rounds: int = 2  # sampling rounds per sub-plan before the fallback picks a candidate
    verifier: str = "oracle"  # seal only
    model: str | None = None  # VLM verifiers: the model name; learned: its checkpoint directory
    false_positive: float = 0.0  # any verifier wrapped in the noisy one (seal only)
    false_negative: float = 0.0
    policy: str = "scripted"
    knobs: str = "misaligned"  # the scripted expert's failure setting
    mode: str = "sync"
    # None: the policy's own (a learned VLA: the model its demonstrations were recorded in; else stock)
    render: str | None = None
    value_ckpt: str = ""  # value only: a `seal train value` checkpoint (file or run directory)
    value_goal: str = "task"  # value only: what the Q-function is conditioned on (task or subplan)
    # -- added later (see _LATER) --
    mismatch: tuple[float, float, float] | None = None  # prediction physics: friction, mass, damping
    check_every: int = 20  # policies that never think: steps between mid-rollout verifier checks
    subplan_budget: int = 200  # control steps one candidate may spend on one sub-plan
    planner: str = ""  # remote policy without reasoning: where its sub-plans come from
    annotations: str | None = None  # annotations planner: JSON file or LeRobot dataset dir
    planner_model: str | None = None  # vlm planner
    prompt: str = "task"  # remote policy without reasoning: prompt with the task or the sub-plan
    policy_ckpt: str = ""  # vla only: checkpoint dir, or shipped 'reason' (default) / 'twin'; also `policy=vla:PATH`
    # seal only: "first" commits the first candidate whose verdict passes (the paper's rule, early exit);
    # "best" waits for every verdict of the round and commits the pass with the highest score
    pick: str = "first"
    # seal only: "slot" (default; `seal eval`'s) takes the verdicts at each chunk boundary in candidate order, so
    # the same seeds give the same episode under any load; "arrival" (`seal run`'s default) takes them as they
    # come in while sampling goes on, the paper's overlap of verification and sampling (see VERIFY_ORDERS)
    verify_order: str = "slot"
    done_check: str = "verify"  # seal only (DONE_CHECKS); in the canonical form unless "trust" (see _LEGACY)
    # -- connection details, never hashed --
    base_url: str | None = field(default=None, metadata=_NO_HASH)  # OpenAI-compatible VLM server
    host: str = field(default="127.0.0.1", metadata=_NO_HASH)  # remote policy server
    port: int = field(default=8000, metadata=_NO_HASH)
    transport: str = field(default="auto", metadata=_NO_HASH)
    request_timeout: float = field(default=30.0, metadata=_NO_HASH)

    def __post_init__(self) -> None:
        from seal.policies import POLICIES
        from seal.verify import VERIFIERS, split_name

        if ":" in self.verifier:  # learned:RUN_DIR names the checkpoint in the verifier's name
            name, path = split_name(self.verifier, self.model)
            object.__setattr__(self, "verifier", name)
            object.__setattr__(self, "model", path)
        if ":" in self.policy:  # `--policy vla:PATH`: the name, and the checkpoint as its own field
            name, _, ckpt = self.policy.partition(":")
            if self.policy_ckpt and self.policy_ckpt != ckpt:
                raise InvalidInput(f"policy {self.policy!r} names a checkpoint and policy_ckpt={self.policy_ckpt!r} "
                                   "another; give one")
            object.__setattr__(self, "policy", name)
            object.__setattr__(self, "policy_ckpt", ckpt)
        _one_of("method", self.method, METHODS)
        _one_of("verifier", self.verifier, VERIFIERS)
        _one_of("policy", self.policy, POLICIES)
        _one_of("knobs setting", self.knobs, KNOBS)
        _one_of("mode", self.mode, MODES)
        _one_of("value_goal", self.value_goal, VALUE_GOALS)
        _one_of("pick", self.pick, PICKS)
        _one_of("verify_order", self.verify_order, VERIFY_ORDERS)
        _one_of("done_check", self.done_check, DONE_CHECKS)
        if self.render is None:
            object.__setattr__(self, "render", self._policy_render() or "stock")
        _one_of("render", self.render, RENDERS)
        _one_of("planner", self.planner, PLANNERS)
        _one_of("prompt", self.prompt, PROMPTS)
        _one_of("transport", self.transport, TRANSPORTS)
        if self.policy_ckpt and self.policy != "vla":
            raise InvalidInput(f"policy_ckpt is for the vla policy, not {self.policy!r}")
        if self.method == "value" and not self.value_ckpt:
            raise InvalidInput("method 'value' needs a trained V-GPS checkpoint: value:value_ckpt=RUN_DIR "
                               "(train one with `seal train value`)")
        if self.mismatch is not None:
            if len(self.mismatch) != 3:
                raise InvalidInput(f"mismatch needs three factors friction,mass,damping; got {self.mismatch!r}")
            self.physics()  # range checks
        if self.request_timeout <= 0:
            raise InvalidInput(f"request_timeout must be > 0, got {self.request_timeout}")
        self.steer_config()  # the loop's own checks (k, rounds, budgets)

    def _policy_render(self) -> str | None:
        """The render model a learned policy was trained in (None: it has no preference)."""
        if self.policy != "vla":
            return None
        from seal.policies.vla.locate import trained_render

        return trained_render(self.policy_ckpt)["mode"]

    def render_warning(self) -> str | None:
        """Why these pixels differ from the ones the policy learned from, or None when they do not."""
        if self.policy != "vla":
            return None
        from seal.policies.vla.locate import trained_render
        from seal.sim.fast_assets import CACHE_VERSION

        trained = trained_render(self.policy_ckpt)
        name = self.policy_ckpt or "the shipped reasoning VLA"
        if trained["mode"] != self.render:
            return (f"{name} was trained on {trained['mode']}-rendered demonstrations but runs with render "
                    f"{self.render!r}: its inputs are out of distribution (leave --render out to use {trained['mode']!r})")
        if self.render == "fast" and trained["fast_version"] not in (None, CACHE_VERSION):
            return (f"{name} was trained on fast render v{trained['fast_version']}; this code renders fast "
                    f"v{CACHE_VERSION}: its inputs differ from its training pixels")
        return None

    # ---- what the pieces get ------------------------------------------------------------------
    def steer_config(self, *, seed: int = 0, max_steps: int | None = None):
        """The loop settings of `seal.steer.engine.Steerer` for one episode."""
        from seal.steer.engine import SteerConfig

        return SteerConfig(method=self.method, k=self.k, rounds=self.rounds, subplan_budget=self.subplan_budget,
                           mode=self.mode, max_steps=max_steps, seed=seed, value_goal=self.value_goal,
                           check_every=self.check_every, pick=self.pick, verify_order=self.verify_order,
                           done_check=self.done_check)

    def physics(self):
        """The prediction worlds' `PhysicsMismatch`, or None for the true physics."""
        if self.mismatch is None:
            return None
        from seal.sim.world import PhysicsMismatch

        friction, mass, damping = self.mismatch
        return PhysicsMismatch(friction=friction, mass=mass, damping=damping)

    @property
    def effective_k(self) -> int:
        return 1 if self.method == "base" else self.k

    @property
    def verifies(self) -> bool:
        """Its candidates go to a verifier (asked of the method's selection object)."""
        return SELECTIONS[self.method].verifies

    @property
    def scores(self) -> bool:
        """It ranks chunks with a scorer loaded from ``value_ckpt``."""
        return SELECTIONS[self.method].scores

    # ---- identity --------------------------------------------------------------------------------
    def canonical(self) -> dict:
        """The settings that matter for this method (base ignores K and the verifier)."""
        d = asdict(self)
        defaults = MethodSpec.__dataclass_fields__
        for f in fields(self):
            if not f.metadata.get("hash", True) or (f.name in _LATER and d[f.name] == defaults[f.name].default):
                d.pop(f.name)
            elif f.name in _LEGACY and d[f.name] == _LEGACY[f.name]:
                d.pop(f.name)
        if d.get("mismatch") is not None:
            d["mismatch"] = list(d["mismatch"])
        if self.method != "seal":
            for name in ("verifier", "model", "false_positive", "false_negative", "rounds", "check_every", "pick",
                         "verify_order", "done_check"):
                d.pop(name, None)
        elif self.verifier == "learned":  # the weights, not the path, decide the verdicts
            from seal.verify.learned import checkpoint_digest as learned_digest

            d["model"] = learned_digest(self.model)
        if self.method == "base":
            d.pop("k")
        if self.method != "value":
            d.pop("value_ckpt")
            d.pop("value_goal")
        else:  # the weights, not the path, decide the results: retraining in place is a new method
            d["value_ckpt"] = checkpoint_digest(self.value_ckpt)
        if self.policy == "vla":  # the weights, not the path, decide the results (as for value_ckpt)
            from seal.policies.vla.locate import checkpoint_digest as vla_digest

            d["policy_ckpt"] = vla_digest(self.policy_ckpt)
        if self.policy != "scripted":  # the expert's failure setting means nothing to another policy
            d.pop("knobs")
        else:
            for name in ("planner", "annotations", "planner_model", "prompt"):
                d.pop(name, None)
        return d

    @property
    def config_hash(self) -> str:
        return hashlib.sha1(json.dumps(self.canonical(), sort_keys=True).encode()).hexdigest()[:10]

    @property
    def label(self) -> str:
        """Short column name for reports: the method, plus what differs from its defaults."""
        default = MethodSpec(method=self.method, value_ckpt=self.value_ckpt).canonical()
        mine = self.canonical()
        extra = [f"{k}={_show(v)}" for k, v in mine.items() if k != "method" and default.get(k) != v]
        extra += [f"{k}={_LEGACY[k]}" for k in _LEGACY if k in default and k not in mine]  # the old behaviour, named
        if self.method == "value":  # which weights, by their run directory's name
            extra.insert(0, f"ckpt={Path(self.value_ckpt).name}")
        return self.method + (f"[{','.join(extra)}]" if extra else "")


def _one_of(what: str, value, valid) -> None:
    if value not in valid:
        raise InvalidInput(f"unknown {what} {value!r}; valid: {', '.join(repr(v) if not v else v for v in valid)}")


def _show(value) -> str:
    return "/".join(str(v) for v in value) if isinstance(value, list) else str(value)


def checkpoint_digest(path: str) -> str:
    """What names a value checkpoint (a run directory or a file in it): its verified bytes."""
    from seal.steer.scoring import value_digest

    return value_digest(path)


# ---- text -> spec (the CLI's flags and `seal eval --methods`) ------------------------------------
def parse_mismatch(text: str) -> tuple[float, float, float] | None:
    """``"1.3,0.8,1.2"`` (or with ``/`` inside a ``--methods`` item) -> (friction, mass, damping)."""
    if text is None or not str(text).strip():
        return None
    parts = [p.strip() for p in str(text).replace("/", ",").split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise InvalidInput(f"--mismatch wants three numbers friction,mass,damping (e.g. 1.3,0.8,1.2); "
                           f"got {text!r}") from None
    if len(values) != 3:
        raise InvalidInput(f"--mismatch wants three numbers friction,mass,damping (e.g. 1.3,0.8,1.2); got {text!r}")
    return values


def convert(key: str, value: str):
    """One ``name=value`` setting of a method, from text to the field's type."""
    if key == "mismatch":
        return parse_mismatch(value)
    current = MethodSpec.__dataclass_fields__[key].default
    try:
        if isinstance(current, bool):
            return value.lower() in ("1", "true", "yes")
        if isinstance(current, int):
            return int(value)
        if isinstance(current, float):
            return float(value)
    except ValueError:
        raise InvalidInput(f"method option {key}={value!r} is not a {type(current).__name__}") from None
    return value


def parse_methods(text: str, **defaults) -> list[MethodSpec]:
    """``"base,seal,seal:k=5:rounds=1"`` -> MethodSpecs; ``defaults`` are the CLI's shared flags
    (None: not given). Inside an item, a mismatch is written with slashes: ``seal:mismatch=1.3/0.8/1.2``."""
    names = [f.name for f in fields(MethodSpec) if f.name != "method"]
    out = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        method, *overrides = item.split(":")
        settings = {k: v for k, v in defaults.items() if v is not None}
        for ov in overrides:
            key, sep, value = ov.partition("=")
            if not sep or key not in names:
                raise InvalidInput(f"bad method option {ov!r} in {item!r}; write name=value with name in "
                                   f"{', '.join(names)}")
            settings[key] = convert(key, value)
        out.append(MethodSpec(method=method, **settings))  # validated once, with every option in place
    if not out:
        raise InvalidInput(f"no methods given; valid: {', '.join(METHODS)}")
    hashes = [m.config_hash for m in out]
    if len(set(hashes)) != len(hashes):
        raise InvalidInput(f"the same method configuration is listed twice in {text!r}")
    return out
