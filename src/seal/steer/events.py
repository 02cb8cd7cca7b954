"""Listeners of the steering loop, in the spirit of openpi's runtime subscribers.

The loop (`seal.steer.engine.Steerer`) publishes what happens as ``(event, fields)``:

    subplan      step, text, reasoning                      a sub-plan starts
    verify_request  request, subplan, round, slot, steps, ended_by
                                                            a candidate goes to the verifier; ``request``
                                                            is the `VerifyRequest` exactly as it is judged
                                                            (ended_by "midway": a mid-rollout check;
                                                            "done_check": the task-level question asked when
                                                            the policy says the task is complete)
    round_end    subplan, round, candidates, reasoning      every candidate of a round has ended;
                                                            the pool's slots still hold their end states
    candidate    round, slot, steps, ended_by, error, snapshot, verdict, t_start, t_end, t_verified
                 (the t_* fields and a verdict's latency_s are clock readings: `seal.steer.trace.TIMING_FIELDS`)
    commit       slot, round, steps, snapshot, ended_by, verdict
    done_check   step, reasoning, verdict, refused, back_to  the policy wrote that the task is complete and
                                                            the verifier was asked whether the instruction
                                                            holds (done_check="verify"); a refusal sends the
                                                            policy back to ``back_to``, its last claimed sub-plan
    episode_end  success, steps, sim_error, ended_by (goal_holds | policy_finished | step_limit | idle |
                 sim_error; with policy_finished also the reasoning that said so)

Subscribers turn that into files and displays: `seal.steer.trace.Trace` (the JSONL trace),
`GridWriter` (a candidate contact sheet per round), `ProgressReporter` (one line of text for a
progress display). A subscriber must not change the loop's objects.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Protocol


class Subscriber(Protocol):
    def on_event(self, event: str, fields: dict) -> None: ...


class GridWriter:
    """``subplanNN_roundR.png`` under ``out_dir``: each candidate's end state, labelled with how it
    ended and its verdict (costs K renders per round)."""

    def __init__(self, pool, out_dir: str | Path):
        self.pool, self.out_dir = pool, Path(out_dir)

    def on_event(self, event: str, fields: dict) -> None:
        if event != "round_end":
            return
        from seal.sim.observation import to_policy_image
        from seal.steer.grid import candidate_grid

        shown = [c for c in fields["candidates"] if c.snapshot is not None]
        views = self.pool.render(("agentview",), slots=[c.slot for c in shown])  # slots still hold end states
        labels = [f"#{c.slot} {c.steps} steps, {c.ended_by}" for c in shown]
        verdicts = [c.verdict.success if c.verdict is not None else None for c in shown]
        r = fields["round"]
        candidate_grid([to_policy_image(v["agentview"]) for v in views], labels, verdicts,
                       self.out_dir / f"subplan{fields['subplan']:02d}_round{r}.png",
                       title=f"{fields['reasoning'].now} (round {r})")


class ProgressReporter:
    """Calls ``show(text)`` with a one-line summary as sub-plans start and candidates end."""

    def __init__(self, show: Callable[[str], None], prefix: str = ""):
        self.show, self.prefix = show, prefix
        self._subplan, self._ended, self._passed = "", 0, 0

    def on_event(self, event: str, fields: dict) -> None:
        if event == "subplan":
            self._subplan, self._ended, self._passed = fields["text"], 0, 0
        elif event == "candidate":
            self._ended += 1
            self._passed += bool(fields["verdict"] and fields["verdict"]["success"])
        elif event == "commit":
            self.show(f"{self.prefix}step {fields['steps']}: committed '{self._subplan}'")
            return
        else:
            return
        self.show(f"{self.prefix}{self._subplan}: {self._ended} candidates ended, {self._passed} passed")
