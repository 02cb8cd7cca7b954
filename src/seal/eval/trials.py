"""What an evaluation run is made of: method configurations and the trials they run.

A *method* is a steering method plus every setting that changes its results (K, rounds,
verifier, the policy's failure setting...). Its config hash names it in the results store, so
two runs of "seal" with different K never mix, and re-running the same command finds its own
finished trials.

A *trial* is (suite, task, trial number). Its init state and seed depend only on those, never on
the method, so every method is compared on the same starts (paired comparisons in reports).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from pathlib import Path

from seal.errors import InvalidInput
from seal.steer.engine import METHODS, VALUE_GOALS
from seal.verify import VERIFIERS

KNOBS = ("clean", "misaligned")


@dataclass(frozen=True)
class MethodSpec:
    """A steering method and the settings that change its results."""

    method: str = "seal"
    k: int = 10
    rounds: int = 2
    verifier: str = "oracle"  # seal only
    model: str | None = None  # VLM verifiers only
    false_positive: float = 0.0  # noisy oracle (seal only)
    false_negative: float = 0.0
    policy: str = "scripted"
    knobs: str = "misaligned"  # the scripted expert's failure setting
    mode: str = "sync"
    render: str = "stock"
    value_ckpt: str = ""  # value only: a `seal train value` checkpoint (file or run directory)
    value_goal: str = "task"  # value only: what the Q-function is conditioned on (task or subplan)

    def __post_init__(self) -> None:
        if self.method == "value" and not self.value_ckpt:
            raise InvalidInput("method 'value' needs a trained V-GPS checkpoint: value:value_ckpt=RUN_DIR "
                               "(train one with `seal train value`)")
        if self.value_goal not in VALUE_GOALS:
            raise InvalidInput(f"unknown value_goal {self.value_goal!r}; valid: {', '.join(VALUE_GOALS)}")
        if self.method not in METHODS:
            raise InvalidInput(f"unknown method {self.method!r}; valid: {', '.join(METHODS)}")
        if self.verifier not in VERIFIERS:
            raise InvalidInput(f"unknown verifier {self.verifier!r}; valid: {', '.join(VERIFIERS)}")
        if self.knobs not in KNOBS:
            raise InvalidInput(f"unknown knobs setting {self.knobs!r}; valid: {', '.join(KNOBS)}")
        if self.policy != "scripted":
            raise InvalidInput(f"unknown policy {self.policy!r}; valid: scripted")
        if self.k < 1 or self.rounds < 1:
            raise InvalidInput(f"need k >= 1 and rounds >= 1, got k={self.k}, rounds={self.rounds}")

    def canonical(self) -> dict:
        """The settings that matter for this method (base ignores K and the verifier)."""
        d = asdict(self)
        if self.method != "seal":
            for name in ("verifier", "model", "false_positive", "false_negative", "rounds"):
                d.pop(name)
        if self.method == "base":
            d.pop("k")
        if self.method != "value":
            d.pop("value_ckpt")
            d.pop("value_goal")
        else:  # the weights, not the path, decide the results: retraining in place is a new method
            d["value_ckpt"] = checkpoint_digest(self.value_ckpt)
        return d

    @property
    def config_hash(self) -> str:
        return hashlib.sha1(json.dumps(self.canonical(), sort_keys=True).encode()).hexdigest()[:10]

    @property
    def effective_k(self) -> int:
        return 1 if self.method == "base" else self.k

    @property
    def label(self) -> str:
        """Short column name for reports: the method, plus what differs from its defaults."""
        default = MethodSpec(method=self.method, value_ckpt=self.value_ckpt).canonical()
        extra = [f"{k}={v}" for k, v in self.canonical().items() if k != "method" and default.get(k) != v]
        if self.method == "value":  # which weights, by their run directory's name
            extra.insert(0, f"ckpt={Path(self.value_ckpt).name}")
        return self.method + (f"[{','.join(extra)}]" if extra else "")


def checkpoint_digest(path: str) -> str:
    """sha1 of a value checkpoint's bytes (a run directory means its checkpoint.pt)."""
    p = Path(path)
    p = p / "checkpoint.pt" if p.is_dir() else p
    if not p.is_file():
        raise InvalidInput(f"no V-GPS checkpoint at {p}; train one with `seal train value`")
    stat = p.stat()
    return _digest(str(p.resolve()), stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=16)
def _digest(path: str, mtime_ns: int, size: int) -> str:  # cached: labels and hashes ask often
    return hashlib.sha1(Path(path).read_bytes()).hexdigest()[:12]


def parse_methods(text: str, **defaults) -> list[MethodSpec]:
    """``"base,seal,seal:k=5:rounds=1"`` -> MethodSpecs; ``defaults`` are the CLI's shared flags."""
    names = {f.name: f.type for f in fields(MethodSpec)}
    out = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        method, *overrides = item.split(":")
        settings = {k: v for k, v in defaults.items() if v is not None}
        for ov in overrides:
            key, sep, value = ov.partition("=")
            if not sep or key not in names or key == "method":
                raise InvalidInput(f"bad method option {ov!r} in {item!r}; write name=value with name in "
                                   f"{', '.join(n for n in names if n != 'method')}")
            settings[key] = _convert(key, value)
        out.append(MethodSpec(method=method, **settings))  # validated once, with every option in place
    if not out:
        raise InvalidInput(f"no methods given; valid: {', '.join(METHODS)}")
    hashes = [m.config_hash for m in out]
    if len(set(hashes)) != len(hashes):
        raise InvalidInput(f"the same method configuration is listed twice in {text!r}")
    return out


def _convert(key: str, value: str):
    current = getattr(MethodSpec(), key)
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


@dataclass(frozen=True)
class TrialSpec:
    """One episode to run: a method on (suite, task, trial)."""

    method: MethodSpec
    suite: str
    task: int
    trial: int
    init_index: int
    seed: int

    @property
    def key(self) -> tuple[str, str, int, int]:
        return (self.method.config_hash, self.suite, self.task, self.trial)

    @property
    def name(self) -> str:
        return f"{self.method.label} {self.suite}/{self.task} #{self.trial}"


def trial_seed(suite: str, task: int, trial: int) -> int:
    """Same for every method; stable across Python runs (no hash randomisation)."""
    return int.from_bytes(hashlib.sha1(f"{suite}/{task}/{trial}".encode()).digest()[:4], "little")


def expand(methods: list[MethodSpec], suites: list[str], tasks: list[int] | None, trials: int) -> list[TrialSpec]:
    """Every (method, suite, task, trial), ordered so one task's trials run together (env pools
    are reused across them) and methods alternate (a run stopped early stays balanced)."""
    from seal.sim.suites import get_task, task_count

    if trials < 1:
        raise InvalidInput(f"--trials must be >= 1, got {trials}")
    out = []
    for suite in suites:
        n = task_count(suite)
        ids = list(range(n)) if tasks is None else tasks
        for task in ids:
            inits = len(get_task(suite, task).init_states())
            for trial in range(trials):
                for m in methods:
                    out.append(TrialSpec(m, suite, task, trial, init_index=trial % inits,
                                         seed=trial_seed(suite, task, trial)))
    return out
