"""The seam between SEAL and whoever acts: a reasoning policy.

A reasoning VLA alternates between thinking (``<think>``: it writes its plan, what it has done
and what it will do now) and acting (``<act>``: action chunks). SEAL only needs those two calls:

- ``reason(obs)``: the three-field reasoning at the start of a sub-plan;
- ``act(obs_batch, reasoning)``: one action chunk per observation (K candidates = K rows),
  each flagged ``think=True`` once the policy considers the sub-plan done and would switch
  back to thinking.

Policies keep per-row state between ``act`` calls (e.g. random streams); ``begin`` starts a
new sub-plan attempt for ``k`` rows.

Contract: chunks are PREDICT_HORIZON actions in [-1, 1]; callers execute ACTION_HORIZON of them.
A policy may set ``thinks = False`` when it never emits <think> (a plain pi0 server with an
external planner, `seal.serving`): the steering loop then lets the verifier end its sub-plans.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Protocol, Sequence

import numpy as np

from seal.errors import InvalidInput
from seal.sim.observation import Observation

PREDICT_HORIZON = 16  # actions predicted per chunk
ACTION_HORIZON = 5  # actions executed before the policy is queried again
THINK, ACT = "<think>", "<act>"
# How a repeated sub-plan text is placed in the plan (`Reasoning.position`); the first is the default
SUBPLAN_REFS = ("after_done", "count")


@dataclass(frozen=True)
class Reasoning:
    """What the policy writes when it thinks: all plans, what is done, what to do now."""

    plans: tuple[str, ...]
    done: tuple[str, ...]
    now: str  # "" when the policy believes the task is complete

    @property
    def finished(self) -> bool:
        return not self.now

    @property
    def index(self) -> int | None:
        """Where ``now`` stands in ``plans`` (`position` by its default rule)."""
        return self.position()

    def position(self, rule: str = SUBPLAN_REFS[0]) -> int | None:
        """Where ``now`` stands in ``plans``, None when it is not in them. Plans repeat texts (two
        "place it in the basket"), and what "it" means depends on which one; the policy says where
        it is by what it lists as done.

        ``after_done``: the occurrence that follows the latest done item it follows in the plan
        (done "pick up the first moka pot. turn on the stove." puts "place it on the stove" after
        the first pick, whatever else the done list claims); with no such item, as ``count``.
        ``count``: the first occurrence at or after the number of done items (or the first at all
        when the done list runs past it). The two agree whenever the done list is a prefix of the
        plan; ``count`` is what every result stored before 2026-12-05 ran with, and it misplaces a
        repeated sub-plan after a done list that claims a later item too (docs/results.md)."""
        if rule not in SUBPLAN_REFS:
            raise InvalidInput(f"unknown sub-plan reference rule {rule!r}; valid: {', '.join(SUBPLAN_REFS)}")
        positions = [i for i, p in enumerate(self.plans) if p == self.now]
        if len(positions) <= 1:
            return positions[0] if positions else None
        by_count = next((i for i in positions if i >= len(self.done)), positions[0])
        if rule == "after_done":
            for item in reversed(self.done):
                after = [i for i in positions if i > 0 and self.plans[i - 1] == item]
                if after:
                    return by_count if by_count in after else after[0]
        return by_count

    def text(self) -> str:
        """The reasoning as the policy writes it between <think> and <act>."""
        plans = " ".join(f"{i + 1}. {p}." for i, p in enumerate(self.plans))
        done = " ".join(f"{p}." for p in self.done) if self.done else "nothing yet."
        now = f"{self.now}." if self.now else "the task is complete."
        return f"Plans: {plans}\nWhat has been done: {done}\nNow I need to do: {now}"


_SECTIONS = re.compile(r"^Plans:(?P<plans>.*)\nWhat has been done:(?P<done>.*)\nNow I need to do:(?P<now>.*)$", re.S)
_ITEM = re.compile(r"(\d+)\.\s(.*?)\.(?=\s\d+\.\s|\s*$)", re.S)


def parse_reasoning(text: Any) -> Reasoning:
    """The inverse of `Reasoning.text()`:

        Plans: 1. pick up the book. 2. place it in the back compartment of the caddy.
        What has been done: pick up the book.
        Now I need to do: place it in the back compartment of the caddy.

    "nothing yet." means no sub-plan is done; "the task is complete." means nothing is left.
    Anything else is an `InvalidInput` that says what is wrong (`seal.serving.protocol` turns it
    into a protocol error when the text came over the wire).
    """
    if not isinstance(text, str):
        raise InvalidInput(f"'reasoning' must be a string, got {type(text).__name__}")
    m = _SECTIONS.match(text.strip())
    if m is None:
        raise InvalidInput("'reasoning' must have three lines 'Plans: 1. ... 2. ...', 'What has been done: ...', "
                           f"'Now I need to do: ...'; got {text[:200]!r}")
    items = _ITEM.findall(m["plans"].strip())
    plans = tuple(t.strip() for _, t in items)
    if not plans or [int(i) for i, _ in items] != list(range(1, len(plans) + 1)):
        raise InvalidInput(f"'reasoning' plans must be numbered '1. ... 2. ...', got {m['plans'].strip()!r}")
    done_text = m["done"].strip()
    done: list[str] = []
    if done_text != "nothing yet.":
        rest = done_text
        while rest:  # done items are plan texts, each followed by "."; match the longest first
            hit = next((p for p in sorted(plans, key=len, reverse=True) if rest.startswith(p + ".")), None)
            if hit is None:
                raise InvalidInput(f"'reasoning' lists as done {rest!r}, which is not one of the plans {list(plans)}")
            done.append(hit)
            rest = rest[len(hit) + 1 :].strip()
    now = m["now"].strip()
    now = "" if now == "the task is complete." else now.removesuffix(".")
    return Reasoning(plans=plans, done=tuple(done), now=now)


def parse_lenient(text: str, instruction: str) -> Reasoning:
    """The three fields of a generated reasoning text; as much of them as can be read."""
    try:
        return parse_reasoning(text)
    except InvalidInput:
        pass
    now = re.search(r"Now I need to do:(.*)", text, re.S)
    now_text = now[1].strip().removesuffix(".").strip() if now else ""
    if now_text == "the task is complete":
        now_text = ""
    plans = tuple(p.strip() for p in re.findall(r"\d+\.\s([^.\n]+)\.", text.split("What has been done:")[0]))
    if not now_text and not plans:
        return Reasoning(plans=(instruction,), done=(), now=instruction)
    if now_text and now_text not in plans:
        plans = (*plans, now_text)
    return Reasoning(plans=plans or (instruction,), done=(), now=now_text)


@dataclass
class ActionChunk:
    """One row of an ``act`` answer."""

    actions: np.ndarray  # (PREDICT_HORIZON, 7); the caller executes the first ACTION_HORIZON
    think: bool = False  # the policy switched to <think>: its sub-plan is done (actions unused)


class ReasoningPolicy(Protocol):
    """Anything that writes sub-plans and acts on them (scripted expert, openpi client, ...).
    Built by name with `seal.policies.make_policy`."""

    thinks: bool  # False: never emits <think> (plain pi0 + a planner); the verifier ends its sub-plans
    # Optional (read with getattr, default None): the side in px at which the policy wants both
    # cameras rendered (a model trained at 64 px gets 64-px renders, not a 224 it would shrink);
    # None: openpi's 224-px view.
    # image_size: int | None

    def close(self) -> None:
        """Release what the policy holds (sockets, threads); a no-op for in-process policies."""
        ...

    def privileged_atoms(self) -> list[str] | None:
        """Goal atoms a scripted policy reads from the privileged `SceneState`; None for a
        policy that sees only images and proprioception (every real VLA)."""
        ...

    def reset(self, instruction: str, seed: int) -> None:
        """Start a new episode of the task with this instruction."""
        ...

    def reason(self, obs: Observation) -> Reasoning: ...

    def begin(self, k: int) -> None:
        """Start ``k`` parallel attempts at the current sub-plan (rows of later ``act`` calls)."""
        ...

    def act(self, obs_batch: Sequence[Observation], reasoning: Reasoning,
            rows: Sequence[int] | None = None) -> list[ActionChunk]:
        """One chunk per observation; ``rows`` says which of the ``begin(k)`` attempts each
        observation belongs to (default: 0..n-1), so finished candidates can drop out."""
        ...


def images_for(policy: ReasoningPolicy, atoms: list[str] | None) -> bool | int:
    """What a policy needs rendered with each observation: nothing (a scripted policy that reads
    the privileged state, ``atoms`` not None), openpi's 224-px view (True), or both cameras at the
    side it declares in ``image_size`` (an int). A declared size wins even over state reading."""
    return getattr(policy, "image_size", None) or (False if atoms is not None else True)
