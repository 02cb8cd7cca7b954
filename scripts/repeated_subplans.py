#!/usr/bin/env python
"""Where the two rules for a repeated sub-plan text disagree, in stored traces (maintainers' tool).

A plan may hold one text twice ("place it on the stove" after each moka pot), and which occurrence the
policy is at decides what "it" is for the verifier and the alignment audit
(`seal.policies.base.Reasoning.position`). For every sub-plan a trace records, this prints whether
``after_done`` (the occurrence after the latest done item it follows) and ``count`` (the occurrence at the
number of done items, every result before 2026-12-05) place it differently, per configuration and task:

    python scripts/repeated_subplans.py ../runs/eval/generalization_v3_runs --suite libero_10 \\
        --configs seal-c143fc3e94,seal-003618e424

One JSON object: {config: {"subplans": n, "disagree": n, "by_task": {task: n}, "example": {...}}}.
"""

import argparse
import json
import sys
from pathlib import Path

from seal.errors import InvalidInput


def audit(runs: Path, suite: str, configs: list[str]) -> dict:
    from seal.policies.base import parse_reasoning

    out = {}
    for config in configs:
        traces = sorted((runs / suite).glob(f"*/{config}/trial*/trace.jsonl"))
        if not traces:
            raise InvalidInput(f"no traces of {config!r} under {runs / suite} (expected <task>/{config}/trialNNN/"
                               f"trace.jsonl; configurations there: "
                               f"{', '.join(sorted({p.name for p in (runs / suite).glob('*/*')})) or 'none'})")
        total, by_task, example = 0, {}, None
        for path in traces:
            task = path.parents[2].name
            for line in path.read_text().splitlines():
                event = json.loads(line)
                if event.get("event") != "subplan" or not event.get("reasoning"):
                    continue
                try:
                    r = parse_reasoning(event["reasoning"])
                except InvalidInput:
                    continue  # garbled reasoning is not a placement question
                total += 1
                if r.position("after_done") != r.position("count"):
                    by_task[task] = by_task.get(task, 0) + 1
                    example = example or {"trace": str(path), "step": event.get("step"), "now": r.now,
                                          "done": list(r.done), "after_done": r.position("after_done"),
                                          "count": r.position("count")}
        out[config] = {"subplans": total, "disagree": sum(by_task.values()), "by_task": by_task, "example": example}
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", type=Path, help="a `seal eval` traces directory (<suite>/<task>/<config>/trialNNN)")
    p.add_argument("--suite", default="libero_10")
    p.add_argument("--configs", required=True, help="comma-separated <method>-<config hash> directory names")
    args = p.parse_args()
    try:
        print(json.dumps(audit(args.runs, args.suite, [c for c in args.configs.split(",") if c])))
    except InvalidInput as e:
        print(f"repeated_subplans.py: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
