"""The scripted reasoning expert: writes sub-plans like a reasoning VLA, then acts on them.

It is SEAL's embedded base policy on a machine without a GPU or pretrained weights, and the
source of demonstrations with true sub-plan boundaries. With `FailureKnobs` it misses its own
plan the way real VLAs do - noisy actions, off-centre grasps, early releases, the wrong object -
while its reasoning text still names the right thing.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar, Sequence

import numpy as np

from seal.errors import InvalidInput
from seal.policies.base import ACTION_HORIZON, PREDICT_HORIZON, ActionChunk, Reasoning
from seal.policies.expert import lay, shelf, shelf_slide, skills, stow, upright
from seal.policies.expert.plan import SubPlan, decompose
from seal.sim.control import METRES_PER_ACTION, RADIANS_PER_ACTION
from seal.sim.goals import GRASP_CHECKS, GoalAtom, hold_atom
from seal.sim.lexicon import category
from seal.sim.observation import Observation
from seal.sim.scene import SceneState


@dataclass(frozen=True)
class FailureKnobs:
    """Seeded ways to miss the plan; each is independent and 0 turns it off.

    action_noise:  std of Gaussian noise on every translation/rotation action entry.
    grasp_offset:  std (metres) of a horizontal offset of the grasp point, drawn per attempt.
    release_early: probability that a place attempt lets go 6-12 cm too high.
    wrong_object:  probability that an attempt picks a different, plausible object, or places
                   at a different region, while the reasoning still names the right one.
    """

    action_noise: float = 0.0
    grasp_offset: float = 0.0
    release_early: float = 0.0
    wrong_object: float = 0.0

    @classmethod
    def misaligned(cls) -> "FailureKnobs":
        """The documented setting where the expert fails often enough for steering to help."""
        return cls(action_noise=0.1, grasp_offset=0.012, release_early=0.15, wrong_object=0.15)

    @classmethod
    def named(cls, name: str) -> "FailureKnobs":
        presets = {"clean": cls(), "misaligned": cls.misaligned()}
        if name not in presets:
            raise InvalidInput(f"unknown knob setting {name!r}; valid: {', '.join(presets)}")
        return presets[name]


@dataclass
class _Attempt:
    """One row's attempt at the current sub-plan: its random stream and drawn perturbations."""

    rng: np.random.Generator
    knobs: skills.Knobs
    acting_on: str  # the object actually acted on (may differ from the plan's)
    target: str | None


@dataclass
class ScriptedExpert:
    """A `ReasoningPolicy` backed by privileged state and motion primitives."""

    goal_atoms: list[GoalAtom]
    instruction: str
    initially_open: tuple[str, ...] = ()
    knobs: FailureKnobs = field(default_factory=FailureKnobs)
    seed: int = 0
    task: str = ""
    # How it tells that an object is in its hand (seal.sim.goals.GRASP_CHECKS): "fingers" (Held) agrees
    # with the oracle's pick check; "pads" (robosuite's Grasped) is the expert before 2026-12-05, which
    # read a mug or moka pot carried on a finger's body as dropped (seal bench grasp) and let go.
    grip: str = GRASP_CHECKS[0]

    def __post_init__(self) -> None:
        if self.grip not in GRASP_CHECKS:
            raise InvalidInput(f"unknown grip {self.grip!r}; valid: {', '.join(GRASP_CHECKS)}")
        self._plans: list[SubPlan] | None = None
        self._current: SubPlan | None = None
        self._attempts: list[_Attempt] = []
        self._round = 0
        self._regions: list[str] = []

    @classmethod
    def for_world(cls, world, knobs: FailureKnobs | None = None, seed: int = 0,
                  grip: str = GRASP_CHECKS[0]) -> "ScriptedExpert":
        return cls(goal_atoms=list(world.goal_atoms), instruction=world.instruction,
                   initially_open=world.task.initially_open(), knobs=knobs or FailureKnobs(), seed=seed,
                   task=world.task.key, grip=grip)

    @classmethod
    def for_task(cls, task, knobs: FailureKnobs | None = None, seed: int = 0,
                 grip: str = GRASP_CHECKS[0]) -> "ScriptedExpert":
        """The expert for a `TaskSpec` (no world needed: it plans from the goal atoms)."""
        return cls(goal_atoms=task.goal_atoms(), instruction=task.instruction, initially_open=task.initially_open(),
                   knobs=knobs or FailureKnobs(), seed=seed, task=task.key, grip=grip)

    # ---- ReasoningPolicy ------------------------------------------------------------------
    thinks: ClassVar[bool] = True  # it emits <think> when its sub-goal holds

    def close(self) -> None:
        """Nothing to release (the protocol's close is for policies behind a socket)."""

    def privileged_atoms(self) -> list[str]:
        """Facts this policy reads from the scene: every sub-goal, and whether each mover is in the hand
        (by its pick check: `skills.in_hand` reads whichever of the two the scene carries)."""
        atoms = {str(a) for a in self.goal_atoms}
        for a in self.goal_atoms:
            if a.predicate in ("in", "on"):
                atoms.add(hold_atom(a.subject, self.grip))
        return sorted(atoms)

    def reset(self, instruction: str | None = None, seed: int | None = None) -> None:
        if instruction is not None:
            self.instruction = instruction
        if seed is not None:
            self.seed = seed
        self._plans, self._current, self._attempts, self._round = None, None, [], 0

    def plans(self, scene: SceneState) -> list[SubPlan]:
        if self._plans is None:
            names = sorted(set(scene.bodies) | set(scene.sites))
            self._plans = decompose(self.goal_atoms, self.instruction, names, task=self.task,
                                    initially_open=self.initially_open)
        return self._plans

    def reason(self, obs: Observation) -> Reasoning:
        scene = _scene(obs, self.grip)
        plans = self.plans(scene)
        # Places a confused policy might put things instead (not the objects' start regions).
        self._regions = sorted(n for n in scene.sites if n.endswith("_region") and not n.endswith("init_region"))
        done = progress(plans, scene)
        current = next((p for p, d in zip(plans, done) if not d), None)
        self._current = current
        finished = tuple(p.text for p, d in zip(plans, done) if d)
        return Reasoning(plans=tuple(p.text for p in plans), done=finished, now=current.text if current else "")

    def begin(self, k: int) -> None:
        self._round += 1
        self._attempts = [self._draw(np.random.default_rng([self.seed, self._round, row])) for row in range(k)]

    def act(self, obs_batch: Sequence[Observation], reasoning: Reasoning,
            rows: Sequence[int] | None = None) -> list[ActionChunk]:
        if self._current is None or reasoning.now != self._current.text:
            raise InvalidInput(f"act() for sub-plan {reasoning.now!r}, but the last reason() chose "
                               f"{self._current.text if self._current else 'nothing'!r}")
        rows = list(range(len(obs_batch))) if rows is None else list(rows)
        if len(rows) != len(obs_batch):
            raise InvalidInput(f"act() got {len(obs_batch)} observations for {len(rows)} rows")
        if not self._attempts or max(rows) >= len(self._attempts):
            self.begin(max(rows) + 1)
        return [self._act_row(_scene(o, self.grip), self._attempts[r]) for o, r in zip(obs_batch, rows)]

    # ---- internals ----------------------------------------------------------------------------
    def _draw(self, rng: np.random.Generator) -> _Attempt:
        sub, kn = self._current, self.knobs
        offset = np.zeros(3)
        if kn.grasp_offset > 0:
            offset[:2] = rng.normal(0.0, kn.grasp_offset, 2)
        early = float(rng.uniform(0.06, 0.12)) if rng.random() < kn.release_early else 0.0
        acting_on, target = (sub.obj, sub.target) if sub else ("", None)
        if sub is not None and rng.random() < kn.wrong_object:
            acting_on, target = self._plausible_mistake(sub, rng)
        return _Attempt(rng=rng, knobs=skills.Knobs(grasp_offset=offset, release_early=early),
                        acting_on=acting_on, target=target)

    def _plausible_mistake(self, sub: SubPlan, rng) -> tuple[str, str | None]:
        """Another object of the task (or region) that a confused policy might act on."""
        movers = sorted({a.subject for a in self.goal_atoms if a.predicate in ("in", "on")} - {sub.obj})
        if sub.skill == "pick" and movers:
            return str(rng.choice(movers)), sub.target
        regions = [n for n in self._regions if n != sub.target]
        if sub.skill == "place" and regions:
            return sub.obj, str(rng.choice(regions))
        return sub.obj, sub.target

    def _act_row(self, scene: SceneState, attempt: _Attempt) -> ActionChunk:
        sub = self._current
        first = self._skill_step(sub, scene, attempt)
        if first.done:
            return ActionChunk(actions=np.zeros((PREDICT_HORIZON, 7)), think=True)
        # Predict the whole chunk by extrapolating the end effector under the controller's
        # measured response; only the first ACTION_HORIZON actions are executed anyway.
        actions = [first.action]
        s = scene
        for _ in range(PREDICT_HORIZON - 1):
            s = _advance(s, actions[-1])
            actions.append(self._skill_step(sub, s, attempt).action)
        out = np.array(actions)
        if self.knobs.action_noise > 0:
            out[:, :6] += attempt.rng.normal(0.0, self.knobs.action_noise, (PREDICT_HORIZON, 6))
        return ActionChunk(actions=np.clip(out, -1.0, 1.0))

    def _skill_step(self, sub: SubPlan, s: SceneState, attempt: _Attempt) -> skills.Step:
        if sub.skill == "pick":
            return skills.pick(s, attempt.acting_on, attempt.knobs, by_handle=self._stowing_next(sub, s, attempt))
        if sub.skill == "place":
            if shelf_slide.level(s, sub.obj, attempt.target) is not None:  # a pan, dish first into a level
                return shelf_slide.slide_in(s, sub.obj, attempt.target, attempt.knobs)
            if stow.stowing(s, sub.obj, attempt.target) is not None:
                return stow.place_inside(s, sub.obj, attempt.target, attempt.knobs)
            if shelf.under_roof(s, sub.obj, attempt.target) is not None:  # a shelf's upper level
                return shelf.place_under_roof(s, sub.obj, attempt.target, attempt.knobs)
            if upright.standing_in(s, sub.obj, attempt.target):  # a book into a caddy's slot
                return upright.place_standing(s, sub.obj, attempt.target, attempt.knobs)
            if lay.laying_direction(s, sub.obj, attempt.target) is not None:  # a bottle into a drawer
                return lay.lay_inside(s, sub.obj, attempt.target)
            return skills.place(s, sub.obj, attempt.target, attempt.knobs, slot=self._slot(sub, attempt, s))
        from seal.policies.expert.articulated import ARTICULATED_SKILLS, in_sweep, push_clear

        if sub.skill == "open":
            # Something to pick later lies where the drawer will be: out of the way first.
            later = tuple(p.obj for p in (self._plans or []) if p.skill == "pick")
            blocker = in_sweep(s, sub.obj, later)
            if blocker is not None:
                return push_clear(s, sub.obj, blocker)
        fn = ARTICULATED_SKILLS.get(sub.skill)
        if fn is None:
            raise InvalidInput(f"no motion primitive for skill {sub.skill!r} ({sub.text!r}) in task {self.task}")
        return fn(s, sub.obj, sub.goal)

    def _slot(self, sub: SubPlan, attempt: _Attempt, s: SceneState) -> tuple[int, int] | None:
        """(i, n): this is the i-th of n objects the plan puts on the same region."""
        sharing = [p.obj for p in self._plans or [] if p.skill == "place" and p.target == sub.target]
        # Containers (a basket) take several objects dropped in anywhere; a surface region
        # (the stove's burner area) must not get them stacked. Nor a container one of them
        # stands tall in (a milk carton in the middle of the basket leaves no room beside it).
        if attempt.target != sub.target or sub.obj not in sharing:
            return None
        if sub.target.endswith("contain_region") and not any(
                o in s.bodies and skills.is_tall(s.bodies[o]) for o in sharing):
            return None
        return sharing.index(sub.obj), len(sharing)

    def _stowing_next(self, sub: SubPlan, s: SceneState, attempt: _Attempt) -> bool:
        """Whether the place after this pick goes through a doorway (then grasp by the handle)."""
        plans = self._plans or []
        nxt = next((plans[i + 1] for i, p in enumerate(plans[:-1]) if p is sub), None)
        if nxt is None or nxt.skill != "place" or nxt.target is None:
            return False
        return stow.stowing(s, attempt.acting_on, nxt.target) is not None


def progress(plans: list[SubPlan], scene: SceneState) -> list[bool]:
    """Which sub-plans are achieved in this state.

    A pick counts as done while its object is in the hand (`skills.in_hand`), or once the place that
    follows it holds.
    """
    facts = scene.facts
    done = []
    for i, p in enumerate(plans):
        holds = skills.in_hand(scene, p.obj) if p.skill == "pick" else facts.get(str(p.goal), False)
        if p.skill == "pick" and not holds and i + 1 < len(plans) and plans[i + 1].skill == "place":
            holds = facts.get(str(plans[i + 1].goal), False)
        done.append(bool(holds))
    # Everything before the first open sub-plan counts as done only if it still holds; the
    # current sub-plan is the first one that does not hold.
    return done


def _scene(obs: Observation, grip: str) -> SceneState:
    """The privileged scene as this expert reads it. `skills.in_hand` takes ``Held`` whenever the scene
    carries it, so the pad-check expert gets the scene without it."""
    if obs.scene is None:
        raise InvalidInput("the scripted expert needs privileged observations: "
                           "observe(privileged_atoms=policy.privileged_atoms())")
    if grip == "pads" and any(k.startswith("Held(") for k in obs.scene.facts):
        return replace(obs.scene, facts={k: v for k, v in obs.scene.facts.items() if not k.startswith("Held(")})
    return obs.scene


def _advance(s: SceneState, action: np.ndarray) -> SceneState:
    """The scene after one action, moving only the end effector (a kinematic guess)."""
    yaw = RADIANS_PER_ACTION * action[5]
    c, si = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -si, 0], [si, c, 0], [0, 0, 1]])
    return replace(s, eef_pos=s.eef_pos + METRES_PER_ACTION * action[:3], finger_axis=rot @ s.finger_axis)


__all__ = ["ScriptedExpert", "FailureKnobs", "progress", "category", "ACTION_HORIZON"]


def scripted_policy(spec, task, *, seed: int = 0) -> ScriptedExpert:
    """`seal.policies.make_policy`'s ``scripted`` entry: the expert with the spec's failure knobs."""
    return ScriptedExpert.for_task(task, FailureKnobs.named(spec.knobs), seed=seed, grip=spec.grip)
