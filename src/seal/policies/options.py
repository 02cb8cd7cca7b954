"""The settings of the built-in policies (registered with them in `seal.policies.POLICIES`).

Light by rule: nothing here loads a model or the simulator, so a method description parses,
checks and hashes these settings in any process. What a factory reads (``options.knobs``,
``options.planner``, ...) is exactly these fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from seal.errors import InvalidInput
from seal.options import PORT, POSITIVE, Options, option, real_in
from seal.sim.goals import GRASP_CHECKS

KNOBS = ("clean", "misaligned")
PLANNERS = ("", "annotations", "vlm")
PROMPTS = ("task", "subplan")
TRANSPORTS = ("auto", "batched", "concurrent", "sequential")


@dataclass(frozen=True)
class ScriptedOptions(Options):
    knobs: str = option("misaligned", "scripted expert's failure setting", choices=KNOBS, what="knobs setting")
    # Every result stored before the expert read Held ran with the pad check: they keep their hashes.
    # (not "grasp": a method's settings reach every slot that has the name, and the oracle's is its pick check)
    grip: str = option("fingers", "scripted expert: an object is in its hand when each finger touches it (fingers) "
                                   "or only when both finger pads do (pads, robosuite's check)",
                        choices=GRASP_CHECKS, legacy="pads", strict=True, what="grasp check")


@dataclass(frozen=True)
class PlannerOptions(Options):
    """A policy that may not reason (plain pi0, the VLA's twin): where its sub-plans come from."""

    planner: str = option("", "sub-plans for a policy that does not reason (plain pi0, the VLA's twin): annotations "
                              "| vlm (none: the instruction is its one sub-plan)", choices=PLANNERS, later=True)
    annotations: str | None = option(None, "annotations planner: JSON file or LeRobot dataset dir (default: the "
                                           "task's decomposition)", later=True)
    planner_model: str | None = option(None, "vlm planner: model name (default gpt-4o)", later=True)
    # read by a remote server's client only; declared here so every stored configuration keeps its hash
    prompt: str = option("task", "remote server without reasoning: prompt with the task or the current sub-plan",
                         choices=PROMPTS, later=True)
    base_url: str | None = option(None, "OpenAI-compatible server URL for a VLM planner or verifier (default: "
                                        "OPENAI_BASE_URL)", hash=False)


@dataclass(frozen=True)
class RemoteOptions(PlannerOptions):
    client: ClassVar[bool] = True  # a client of a policy server: `seal serve` does not serve it
    host: str = option("127.0.0.1", "remote policy server host (or a ws:// URI)", hash=False)
    port: int = option(8000, "remote policy server port", type=PORT, hash=False)
    transport: str = option("auto", "remote: how K observations are sent", choices=TRANSPORTS, hash=False)
    request_timeout: float = option(30.0, "remote: seconds to wait for one reply", type=POSITIVE, hash=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.request_timeout <= 0:
            raise InvalidInput(f"request_timeout must be > 0, got {self.request_timeout}")


@dataclass(frozen=True)
class VLAOptions(PlannerOptions):
    """A learned VLA checkpoint: ``policy_ckpt`` (also written ``--policy vla:PATH``)."""

    checkpoint: ClassVar[str] = "policy_ckpt"
    policy_ckpt: str = option("", "vla: checkpoint directory, or shipped 'reason' (default) / 'twin'; also written "
                                  "policy=vla:PATH", later=True, strict=True, flag=False)
    noise_scale: float = option(1.0, "vla: scale of the flow's starting noise (1: as trained; 0: every chunk from zero "
                                     "noise, one deterministic chunk per observation)", type=real_in(0.0), later=True,
                                strict=True)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (self.noise_scale >= 0.0 and math.isfinite(self.noise_scale)):
            raise InvalidInput(f"noise_scale must be a finite number >= 0, got {self.noise_scale}")

    def weights(self):
        from seal.policies.vla.locate import CHECKPOINT, resolve_checkpoint

        return CHECKPOINT, resolve_checkpoint(self.policy_ckpt)

    def preferred_render(self) -> str:
        """The render model its demonstrations were recorded in: its inputs come from there."""
        from seal.policies.vla.locate import trained_render

        return trained_render(self.policy_ckpt)["mode"]

    def render_warning(self, render: str) -> str | None:
        from seal.policies.vla.locate import trained_render
        from seal.sim.fast_assets import CACHE_VERSION

        trained = trained_render(self.policy_ckpt)
        name = self.policy_ckpt or "the shipped reasoning VLA"
        if trained["mode"] != render:
            return (f"{name} was trained on {trained['mode']}-rendered demonstrations but runs with render "
                    f"{render!r}: its inputs are out of distribution (leave --render out to use {trained['mode']!r})")
        if render == "fast" and trained["fast_version"] not in (None, CACHE_VERSION):
            return (f"{name} was trained on fast render v{trained['fast_version']}; this code renders fast "
                    f"v{CACHE_VERSION}: its inputs differ from its training pixels")
        return None

