"""The steering loop's settings, declared and checked once.

`LoopSettings` are what a method sets in the loop (K, rounds, budgets, how verdicts are taken);
`seal.steer.method.MethodSpec` carries them (plus the policy, verifier and scorer and where
they run), and `SteerConfig` is them plus one episode's seed and step limit, which is what
`seal.steer.engine.Steerer` runs with. The methods themselves are plug-ins: ``METHODS`` names
each one's candidate-selection class (`seal.steer.selection`), imported on first use.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from seal.errors import InvalidInput
from seal.options import COUNT, check_choices, option
from seal.policies.base import ACTION_HORIZON, SUBPLAN_REFS
from seal.registry import Plugin, Registry

if TYPE_CHECKING:
    from seal.steer.selection import Selection

METHODS = Registry("method", {
    "base": Plugin("seal.steer.selection:Selection", summary="the policy alone: K=1, nothing verified"),
    "random": Plugin("seal.steer.selection:RandomSelection", summary="K candidates, a random finished one"),
    "value": Plugin("seal.steer.selection:ValueSelection",
                    summary="V-GPS: at every chunk, the best of K by a `seal train value` checkpoint (--value-ckpt)"),
    "seal": Plugin("seal.steer.selection:SealSelection", summary="K candidates, verified; the first pass wins"),
})

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


@dataclass(frozen=True)
class LoopSettings:
    """What a method sets in the steering loop. ``per_method`` settings count (in a config hash)
    only for the methods whose selection uses them (`Selection.uses`)."""

    method: str = option("seal", "how candidates are selected", flag=False)
    k: int = option(10, "candidates per sub-plan", type=COUNT, per_method=True)
    rounds: int = option(2, "sampling rounds per sub-plan before the fallback picks a candidate", type=COUNT,
                         per_method=True)
    subplan_budget: int = option(200, "control steps one candidate may spend on one sub-plan", type=int, later=True)
    mode: str = option("sync", "sync: every slot moves to the winner's predicted state | replay: the winner's actions "
                               "are executed in a separate evaluation world", choices=MODES)
    check_every: int = option(20, "policies without <think>: steps between mid-rollout verifier checks", type=int,
                              later=True, per_method=True)
    value_goal: str = option("task", "value: condition the Q-function on the task (V-GPS) or the sub-plan",
                             choices=VALUE_GOALS, per_method=True)
    # seal only: "first" commits the first candidate whose verdict passes (the paper's rule, early exit);
    # "best" waits for every verdict of the round and commits the pass with the highest score
    pick: str = option("first", "seal: the first candidate to pass, or the best-scored pass of a whole round",
                       choices=PICKS, later=True, per_method=True, flag=False)
    verify_order: str = option(
        "slot", "seal: slot (`seal eval`'s default) waits at each chunk boundary for the verdicts of the candidates "
                "that ended there and takes them candidate 0 first: the same seeds give the same trace under any load "
                "| arrival (`seal run`'s default): verdicts are taken as they come in while sampling goes on, the "
                "paper's early exit, so thread timing can change the winner",
        choices=VERIFY_ORDERS, later=True, per_method=True)
    done_check: str = option(
        "verify", "seal: verify asks the verifier whether the instruction holds when the policy writes that the task "
                  "is complete, and a refusal sends it back to its last claimed sub-plan | trust: the episode ends on "
                  "the policy's word (results before the check)",
        choices=DONE_CHECKS, legacy="trust", per_method=True)
    # seal: a plan may repeat a sub-plan text ("place it on the stove" twice), and which one the policy is at
    # decides what "it" is for the verifier and the alignment audit (`seal.policies.base.Reasoning.position`)
    subplan_ref: str = option(
        "after_done", "seal: where a repeated sub-plan text stands in the plan: after_done places it after the "
                      "latest done item it follows | count: at the number of done items (results before "
                      "2026-12-05; wrong when the policy lists a later sub-plan as done)",
        choices=SUBPLAN_REFS, legacy="count", per_method=True)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InvalidInput(f"unknown method {self.method!r}; valid: {', '.join(METHODS.names)}")
        check_choices(self)
        if self.k < 1 or self.rounds < 1 or self.subplan_budget < ACTION_HORIZON or self.check_every < ACTION_HORIZON:
            raise InvalidInput(f"need k >= 1, rounds >= 1, subplan_budget >= {ACTION_HORIZON}, check_every >= "
                               f"{ACTION_HORIZON}; got k={self.k}, rounds={self.rounds}, "
                               f"subplan_budget={self.subplan_budget}, check_every={self.check_every}")

    def selection(self) -> "Selection":
        """The method's candidate-selection object, for these settings."""
        return METHODS.factory(self.method).for_settings(self)

    @property
    def effective_k(self) -> int:
        """Candidates sampled per round (and pool slots needed): the method's own answer (base: 1)."""
        return self.selection().k(self)


@dataclass(frozen=True)
class SteerConfig(LoopSettings):
    """The loop settings of one episode."""

    max_steps: int | None = None  # default: the suite's limit (520 for LIBERO-10)
    seed: int = 0
