"""What one steered episode produced (`seal.steer.engine.Steerer.run`)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class SteerResult:
    task: str
    instruction: str
    init_index: int
    method: str
    success: bool = False
    sim_error: bool = False
    steps: int = 0
    wall_s: float = 0.0
    subplans: list[str] = field(default_factory=list)
    goal_status: dict = field(default_factory=dict)
    verifier_calls: int = 0
    input_tokens: int = 0
    output_tokens: int = 0
    cost_usd: float = 0.0
    rounds: int = 0
    fallbacks: int = 0
    verifier_errors: int = 0  # verifications that got no answer (transient errors past their retries)
    verifier_unavailable: bool = False  # in most rounds that asked the verifier, it never answered
    divergence: list[float] = field(default_factory=list)  # replay mode: per commit, max |qpos| gap
    # per committed sub-plan: did the executed chunks achieve it by simulator truth? (True/False; None =
    # the sub-plan names nothing the oracle can ground). Measured for every method, never used to decide.
    aligned: list = field(default_factory=list)
    # wall time of the loop's stages; predict_s includes the workers' physics and rendering, whose
    # own (summed) times physics_cpu_s / render_cpu_s say how predict_s splits between the two
    timing: dict = field(default_factory=lambda: {"sampling_s": 0.0, "predict_s": 0.0, "verify_wait_s": 0.0,
                                                  "physics_cpu_s": 0.0, "render_cpu_s": 0.0})
    executed_actions: list = field(default_factory=list)
    # per "the task is complete" the policy wrote (done_check="verify"): did the verifier let it end?
    done_checks: list = field(default_factory=list)
    trace: str = ""
    # why the loop stopped: goal_holds | policy_finished (the policy wrote "the task is complete") |
    # step_limit | idle (it kept thinking without acting) | sim_error
    ended_by: str = ""
    last_reasoning: str = ""  # with policy_finished: the text that said so
