"""Sub-plans for a policy server that acts but does not reason (plain pi0, pi0.5).

SEAL steers sub-plan by sub-plan, so a policy that writes no plan needs someone who does:

- `AnnotationPlanner`: a known task's sub-plans, in order - from a JSON file, from a LeRobot
  dataset's episode annotations (``subplans`` in ``meta/episodes.jsonl``), or from the task's
  own decomposition (what `seal demos record` writes as annotations);
- `VLMPlanner`: a vision-language model looks at the front camera and writes the plan, what is
  done and what to do now, through the same OpenAI-compatible backend as the VLM verifier
  (``OPENAI_API_KEY`` / ``OPENAI_BASE_URL``, or an explicit base URL).

A planner is asked once per sub-plan (`next`); the engine ends each sub-plan on its step budget
or when the verifier accepts the candidate's state, then asks again.
"""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path
from typing import Any, Protocol, Sequence

from seal.errors import InvalidInput, SealError
from seal.policies.base import Reasoning
from seal.sim.observation import Observation

PLANNERS = ("annotations", "vlm")


class PlannerError(SealError, RuntimeError):
    """The planner could not produce a usable plan (model unreachable, unusable answer)."""


class Planner(Protocol):
    def reset(self, instruction: str) -> None: ...

    def next(self, obs: Observation) -> Reasoning:
        """The reasoning for the next sub-plan (``now == ""`` once nothing is left)."""
        ...


class AnnotationPlanner:
    """Walks a fixed list of sub-plans: the i-th call returns sub-plan i (and 0..i-1 as done)."""

    def __init__(self, plans: Sequence[str]):
        plans = tuple(str(p).strip() for p in plans)
        if not plans or not all(plans):
            raise InvalidInput(f"an annotation planner needs a non-empty list of non-empty sub-plans, got {list(plans)}")
        self.plans = plans
        self._i = 0

    @classmethod
    def for_task(cls, spec) -> "AnnotationPlanner":
        """The task's own decomposition (the sub-plans `seal demos record` annotates)."""
        from seal.policies.expert.plan import plan_task

        return cls([p.text for p in plan_task(spec)])

    @classmethod
    def from_json(cls, path: str | Path, task: str, instruction: str = "") -> "AnnotationPlanner":
        """``{"libero_10/0": ["pick up ...", ...], "<instruction>": [...]}``: by task key, else by instruction."""
        path = Path(path)
        try:
            table = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise InvalidInput(f"cannot read sub-plan annotations from {path}: {exc}") from None
        if not isinstance(table, dict):
            raise InvalidInput(f"{path} must hold a JSON object mapping task key or instruction to a list of sub-plans")
        plans = table.get(task) or table.get(instruction)
        if not isinstance(plans, list):
            raise InvalidInput(f"{path} has no sub-plans for task {task!r} (or its instruction); it has "
                               f"{sorted(table)[:20]}")
        return cls(plans)

    @classmethod
    def from_dataset(cls, root: str | Path, instruction: str) -> "AnnotationPlanner":
        """The first annotated episode of a LeRobot dataset with this instruction."""
        from seal.datasets.lerobot import open_dataset

        data = open_dataset(Path(root))
        seen = set()
        for i in range(data.num_episodes):
            record = data.episode_meta(i)
            seen.update(record.get("tasks") or [])
            if instruction in (record.get("tasks") or []) and record.get("subplans"):
                return cls(record["subplans"])
        raise InvalidInput(f"dataset {root} has no annotated episode for {instruction!r}; its instructions: "
                           f"{sorted(seen)[:20]}")

    def reset(self, instruction: str) -> None:
        self._i = 0

    def next(self, obs: Observation) -> Reasoning:
        i = min(self._i, len(self.plans))
        self._i += 1
        now = self.plans[i] if i < len(self.plans) else ""
        return Reasoning(plans=self.plans, done=self.plans[:i], now=now)


_PROMPT = """\
You plan for a robot arm working at a table. Split the task into short steps that a low-level \
controller can carry out one at a time, such as "pick up the red mug" or "place it on the \
left plate", then look at the camera picture and decide which steps are already finished.

Task: {instruction}
{known}
Answer with one JSON object and nothing else:
{{"plans": ["step 1", "step 2", ...], "done": ["finished steps, copied from plans"], \
"now": "the step to do next, copied from plans, or an empty string if the task is finished"}}"""


class VLMPlanner:
    """A VLM writes the three-field reasoning from the current front-camera view."""

    def __init__(self, model: str = "gpt-4o", base_url: str | None = None, *, api_key: str | None = None,
                 timeout_s: float = 60.0, max_retries: int = 2):
        from seal.vlm import require_key, require_sdk, Secrets

        require_sdk("openai")
        require_key("openai", api_key)
        from openai import OpenAI

        kwargs: dict[str, Any] = {"timeout": timeout_s, "max_retries": max_retries}
        if api_key is not None:  # else the SDK reads OPENAI_API_KEY itself
            kwargs["api_key"] = api_key
        if base_url is not None:  # else OPENAI_BASE_URL or the SDK's default
            kwargs["base_url"] = base_url
        self._client = OpenAI(**kwargs)
        self._secrets = Secrets("openai", api_key)
        self.model = model
        self.calls = 0
        self.reset("")

    def reset(self, instruction: str) -> None:
        self._instruction = instruction
        self._plans: tuple[str, ...] | None = None
        self._asked: list[str] = []

    def next(self, obs: Observation) -> Reasoning:
        if obs.agent is None:
            raise InvalidInput("the VLM planner needs the front camera image; observe(images=True)")
        known = ""
        if self._plans:
            known = ("Your plan so far (keep it unless it is clearly wrong): "
                     + json.dumps(list(self._plans)) + "\nSteps already attempted: " + json.dumps(self._asked) + "\n")
        from seal.vlm import encode_image

        url = "data:image/png;base64," + base64.b64encode(encode_image(obs.agent, "png", "agent")).decode("ascii")
        content = [{"type": "text", "text": _PROMPT.format(instruction=self._instruction or obs.prompt, known=known)},
                   {"type": "image_url", "image_url": {"url": url}}]
        try:
            resp = self._client.chat.completions.create(model=self.model, temperature=0.0,
                                                        messages=[{"role": "user", "content": content}])
        except Exception as exc:
            raise PlannerError(self._secrets.scrub(f"VLM planner call failed: {type(exc).__name__}: {exc}")[:500]) \
                from None
        self.calls += 1
        text = (resp.choices[0].message.content if resp.choices else None) or ""
        reasoning = parse_plan_answer(self._secrets.scrub(text))
        self._plans = reasoning.plans
        if reasoning.now:
            self._asked.append(reasoning.now)
        return reasoning


def parse_plan_answer(text: str) -> Reasoning:
    """The planner's JSON answer (code fences and text around the object are tolerated)."""
    m = re.search(r"\{.*\}", text, flags=re.S)
    try:
        data = json.loads(m.group(0)) if m else None
    except ValueError:
        data = None
    if not isinstance(data, dict):
        raise PlannerError(f"VLM planner answer is not a JSON object with plans/done/now: {text[:300]!r}")
    plans, done, now = data.get("plans"), data.get("done", []), data.get("now")
    if not isinstance(plans, list) or not plans or not all(isinstance(p, str) and p.strip() for p in plans):
        raise PlannerError(f"VLM planner 'plans' must be a non-empty list of strings, got {plans!r}")
    plans = [p.strip() for p in plans]
    if not isinstance(done, list) or not all(isinstance(d, str) for d in done):
        raise PlannerError(f"VLM planner 'done' must be a list of strings, got {done!r}")
    if not isinstance(now, str):
        raise PlannerError(f"VLM planner 'now' must be a string, got {now!r}")
    now = now.strip()
    if now and now not in plans:
        raise PlannerError(f"VLM planner 'now' {now!r} is not one of its plans {plans}")
    return Reasoning(plans=tuple(plans), done=tuple(d.strip() for d in done if d.strip() in plans), now=now)


def make_planner(name: str, *, spec, annotations: str | None = None, model: str | None = None,
                 base_url: str | None = None):
    """``annotations`` (a JSON file or LeRobot dataset dir via ``annotations``; default: the
    task's decomposition) or ``vlm``."""
    if name == "annotations":
        if annotations is None:
            return AnnotationPlanner.for_task(spec)
        path = Path(annotations)
        if path.is_dir():
            return AnnotationPlanner.from_dataset(path, spec.instruction)
        return AnnotationPlanner.from_json(path, spec.key, spec.instruction)
    if name == "vlm":
        return VLMPlanner(model or "gpt-4o", base_url)
    raise InvalidInput(f"unknown planner {name!r}; valid: {', '.join(PLANNERS)}")
