"""`seal bench verifier`: a verifier against simulator truth on verification cases.

Cases come from ``--data`` (a `seal verify collect` directory) or, without it, from a small
held-out set collected on the spot into ``runs/verifier/heldout/<suite>-<tasks>-k<K>`` (reused when
it is already there): init states drawn fresh from the ``fresh-heldout`` seed range, which no
training collection (``fresh-train``) and no shipped init state uses (`seal.collect`).

Every verifier gets exactly the `VerifyRequest` it would get in a SEAL round (for the oracle
and ``noisy``, the end state carries the recorded truth of the grounded atoms). Requests go in
batches of ``--k`` (10): a verifier with ``verify_batch`` (``learned``) judges a batch in one
call (after one untimed warm-up batch), the others get the batch's requests concurrently.
``ms_per_verdict`` is the wall time of the batches over the number of cases.

Positive = success. An unknown verdict counts as a predicted failure (SEAL never commits on
it) and is also counted apart. VLM answers are cached on disk (``--cache-dir``, keyed by
backend, model, settings, prompt and the images' pixels), so a re-run pays nothing:
``cost_usd`` is what this run spent, ``cost_usd_uncached`` what the answers cost when first paid.

A verifier that gives a confidence (``Verdict.score``: the learned one's P(success)) also gets
``operating_points``: the same figures at other thresholds, so one run shows what a stricter
verifier would trade. ``--min-precision P`` picks the lowest threshold whose precision on these
cases reaches P (the most recall at that precision). Pick it on a calibration set that shares no
start with the set you report on, then score the reported set with ``--threshold``.

``ci95``: 95% intervals of accuracy, precision and recall that resample whole start states (the
cases of one start share its scene and are far from independent: a Wilson interval over cases
would be too narrow). Two verifiers whose figures fall inside each other's intervals on these
cases are not told apart by them.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import numpy as np

from seal.errors import InvalidInput
from seal.verify import dataset as ds
from seal.verify.dataset import binary_metrics

DEFAULT_CACHE = Path.home() / ".cache" / "seal" / "verifier-answers"
HELDOUT_DIR = Path("runs") / "verifier" / "heldout"
HELDOUT_PER_TASK = 20
THRESHOLDS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98)


def _build(args):
    from seal.verify import make_verifier, split_name

    name, model = split_name(args.verifier, getattr(args, "model", None))
    opts: dict = {}
    if name in ("openai", "gemini"):
        opts["cache_dir"] = Path(args.cache_dir) if getattr(args, "cache_dir", None) else DEFAULT_CACHE
    fp = getattr(args, "false_positive", None)
    fn = getattr(args, "false_negative", None)
    if name == "noisy" and fp is None and fn is None:
        raise InvalidInput("--verifier noisy needs --false-positive and/or --false-negative rates")
    if getattr(args, "threshold", None) is not None:
        if name != "learned":
            raise InvalidInput(f"--threshold applies to --verifier learned (a P(success) cut), not {name!r}")
        opts["threshold"] = args.threshold
    return make_verifier(name, model=model, base_url=getattr(args, "base_url", None), false_positive=fp or 0.0,
                         false_negative=fn or 0.0, seed=0, **opts)


def heldout_set(args) -> Path:
    """The held-out cases scored without --data (collected once, then reused)."""
    from seal.collect import CollectOptions, collect
    from seal.sim.suites import parse_task_ids

    tasks = parse_task_ids(args.suite, args.tasks or "0,1,7")
    out = HELDOUT_DIR / f"{args.suite}-{'_'.join(map(str, tasks))}-k{args.k}"
    opts = CollectOptions(suite=args.suite, tasks=tasks, per_task=HELDOUT_PER_TASK, k=args.k, balance=True,
                          init_source="fresh-heldout", inits_per_task=10, max_steps=getattr(args, "max_steps", None))
    collect(opts, out)
    return out


async def _judge_all(verifier, requests, k: int):
    verdicts, wall = [], 0.0
    batched = hasattr(verifier, "verify_batch")
    if batched and requests:  # one untimed batch first: the first forward pass pays one-off setup
        verifier.verify_batch(requests[:k])
    for start in range(0, len(requests), k):
        batch = requests[start:start + k]
        t0 = time.perf_counter()
        if batched:
            out = verifier.verify_batch(batch)
        else:
            out = await asyncio.gather(*(verifier.verify(r) for r in batch))
        wall += time.perf_counter() - t0
        verdicts += out
    closer = getattr(verifier, "aclose", None)
    if closer is not None:
        await closer()
    return verdicts, wall


def operating_points(labels, scores, thresholds=THRESHOLDS) -> list[dict]:
    """The figures a verifier with confidences ``scores`` would get at each threshold."""
    y, s = np.asarray(labels, dtype=bool), np.asarray(scores, dtype=float)
    points = []
    for t in thresholds:
        m = binary_metrics(y, s >= t)
        points.append({"threshold": t, **{key: m[key] for key in ("accuracy", "precision", "recall", "fp_rate")}})
    return points


def pick_threshold(labels, scores, min_precision: float) -> dict:
    """The lowest threshold (so the most recall) at which precision reaches ``min_precision``;
    ``threshold`` None when no threshold that passes anything reaches it."""
    if not 0.0 < min_precision <= 1.0:
        raise InvalidInput(f"--min-precision must be in (0, 1], got {min_precision}")
    y, s = np.asarray(labels, dtype=bool), np.asarray(scores, dtype=float)
    for t in np.unique(s):  # candidate cuts: the scores themselves, ascending
        m = binary_metrics(y, s >= t)
        if m["precision"] is not None and m["precision"] >= min_precision:
            return {"min_precision": min_precision, "threshold": round(float(t), 6), "cases": len(y),
                    **{key: m[key] for key in ("accuracy", "precision", "recall", "fp_rate")}}
    return {"min_precision": min_precision, "threshold": None, "cases": len(y)}


def start_intervals(labels, predicted, starts, *, resamples: int = 2000, seed: int = 0) -> dict:
    """Percentile-bootstrap 95% intervals of accuracy, precision and recall, resampling start states
    (``starts``: one key per case) with replacement and keeping each start's cases together."""
    y, p = np.asarray(labels, dtype=bool), np.asarray(predicted, dtype=bool)
    keys, which = np.unique(np.asarray(starts, dtype=str), return_inverse=True)
    counts = np.zeros((len(keys), 4))  # per start: tp, fp, fn, tn
    for col, hit in enumerate((y & p, ~y & p, y & ~p, ~y & ~p)):
        np.add.at(counts[:, col], which, hit)
    draws = np.random.default_rng(seed).multinomial(len(keys), np.full(len(keys), 1.0 / len(keys)), size=resamples)
    tp, fp, fn, tn = (draws @ counts).T
    with np.errstate(invalid="ignore", divide="ignore"):
        figures = {"accuracy": (tp + tn) / (tp + fp + fn + tn), "precision": tp / (tp + fp), "recall": tp / (tp + fn)}

    def interval(values):
        values = values[np.isfinite(values)]
        return [round(float(np.percentile(values, q)), 4) for q in (2.5, 97.5)] if len(values) else None

    return {"by": "start state", "starts": len(keys), "resamples": resamples,
            **{name: interval(values) for name, values in figures.items()}}


def score(verifier, data: Path, *, k: int = 10, limit: int | None = None, errors_png: Path | None = None,
          min_precision: float | None = None) -> dict:
    """Metrics of ``verifier`` on the cases under ``data``; with ``errors_png``, a contact sheet of
    the cases it got wrong (`error_sheet`); with ``min_precision``, the threshold that reaches it."""
    cases = list(ds.iter_cases(data, limit=limit))
    if not cases:
        raise InvalidInput(f"{data} holds no cases")
    requests = [ds.to_request(c) for c in cases]
    verdicts, wall = asyncio.run(_judge_all(verifier, requests, k))
    labels = [c.label for c in cases]
    predicted = [v.success is True for v in verdicts]
    out = {"verifier": verifier.name, "data": str(data), "cases": len(cases), "k": k, **binary_metrics(labels, predicted)}
    starts = [ds.init_key_of(c.row["task"], c.row["init_source"], c.row["init_index"]) for c in cases]
    out["ci95"] = start_intervals(labels, predicted, starts)
    out["unknown"] = sum(v.success is None for v in verdicts)
    out["per_kind"] = {}
    for kind in ds.KINDS:
        idx = [i for i, c in enumerate(cases) if c.kind == kind]
        if idx:
            out["per_kind"][kind] = binary_metrics([labels[i] for i in idx], [predicted[i] for i in idx])
    out["per_task"] = {}
    for task in sorted({c.row["task"] for c in cases}):
        idx = [i for i, c in enumerate(cases) if c.row["task"] == task]
        out["per_task"][task] = binary_metrics([labels[i] for i in idx], [predicted[i] for i in idx])
    out["ms_per_verdict"] = round(1000 * wall / len(cases), 3)
    out["input_tokens"] = sum(v.input_tokens for v in verdicts)
    out["output_tokens"] = sum(v.output_tokens for v in verdicts)
    out["cost_usd"] = round(sum(v.cost_usd for v in verdicts), 6)
    out["cached"] = sum(bool(v.extra.get("cached")) for v in verdicts)
    out["cost_usd_uncached"] = round(out["cost_usd"] + sum(v.extra.get("original_cost_usd", 0.0) for v in verdicts), 6)
    out["errors"] = sum(bool(v.extra.get("error")) for v in verdicts)
    scores = [v.score for v in verdicts]
    if all(sc is not None for sc in scores) and any(0.0 < sc < 1.0 for sc in scores):  # not a yes/no verifier
        out["threshold"] = getattr(verifier, "threshold", None)
        out["operating_points"] = operating_points(labels, scores)
        if min_precision is not None:
            out["calibrated"] = pick_threshold(labels, scores, min_precision)
    elif min_precision is not None:
        raise InvalidInput(f"--min-precision needs a verifier that gives a confidence (learned); {verifier.name} does not")
    if errors_png is not None:
        wrong = [i for i, (label, verdict) in enumerate(zip(labels, verdicts)) if verdict.success is not label]
        out["error_sheet"] = error_sheet([(requests[i], cases[i], verdicts[i]) for i in wrong], errors_png)
    return out


def error_sheet(rows: list, path: Path, limit: int = 16, side: int = 160) -> dict:
    """One line per wrong verdict, up to ``limit``: the three images the verifier saw (sub-plan start,
    candidate's end, wrist at the end) and above them the case, the truth and the verdict. False
    successes first: they are the costly mistakes (SEAL commits a wrong chunk)."""
    from PIL import Image, ImageDraw

    from seal.steer.grid import label_font

    rows = sorted(rows, key=lambda r: r[1].label)[:limit]  # label False (a false success) first
    head = 28
    sheet = Image.new("RGB", (3 * side, max(1, len(rows)) * (side + head)), "white")
    draw = ImageDraw.Draw(sheet)
    font = label_font(11)
    for n, (request, case, verdict) in enumerate(rows):
        y = n * (side + head)
        for col, image in enumerate((request.first_agent, request.final_agent, request.final_wrist)):
            sheet.paste(Image.fromarray(np.asarray(image)).resize((side, side)), (col * side, y + head))
        truth = "success" if case.label else "failure"
        said = {True: "success", False: "failure", None: "unknown"}[verdict.success]
        draw.text((3, y + 2), f"{case.row['task']} | {case.row['subplan']}"[:78], fill="black", font=font)
        draw.text((3, y + 14), f"truth {truth}, verifier said {said} {verdict.rationale}"[:78],
                  fill="firebrick" if not case.label else "navy", font=font)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)
    return {"path": str(path), "shown": len(rows)}


def markdown(result: dict) -> str:
    head = ("| cases | n | accuracy | precision | recall | F1 | FP rate | FN rate | TP | FP | FN | TN |\n"
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n")

    def row(name, m):
        c = m["confusion"]
        cells = [m[key] for key in ("n", "accuracy", "precision", "recall", "f1", "fp_rate", "fn_rate")]
        cells = ["-" if v is None else (f"{v:.3f}" if isinstance(v, float) else str(v)) for v in cells]
        return f"| {name} | " + " | ".join(cells + [str(c[x]) for x in ("tp", "fp", "fn", "tn")]) + " |\n"

    text = (f"**{result['verifier']}** on `{result['data']}`: {result['cases']} cases, "
            f"{result['ms_per_verdict']} ms per verdict (K={result['k']}), {result['unknown']} unknown, "
            f"{result['input_tokens']} input + {result['output_tokens']} output tokens, "
            f"${result['cost_usd']:.4f} spent (${result['cost_usd_uncached']:.4f} uncached)\n\n")
    ci = result.get("ci95")
    if ci and ci.get("accuracy"):
        span = lambda name: "-" if ci[name] is None else f"[{ci[name][0]:.3f}, {ci[name][1]:.3f}]"
        text += (f"95% intervals, resampling the {ci['starts']} start states: accuracy {span('accuracy')}, "
                 f"precision {span('precision')}, recall {span('recall')}\n\n")
    text += head + row("all", result)
    for kind, m in result["per_kind"].items():
        text += row(kind, m)
    if len(result.get("per_task", {})) > 1:  # which tasks the mistakes come from (held-out tasks vs the rest)
        text += "\nBy task:\n\n" + head.replace("| cases |", "| task |", 1)
        for task, m in result["per_task"].items():
            text += row(task, m)
    if result.get("operating_points"):
        text += (f"\nAt other thresholds (this run: {result['threshold']}):\n\n"
                 "| threshold | accuracy | precision | recall | FP rate |\n| ---: | ---: | ---: | ---: | ---: |\n")
        for p in result["operating_points"]:
            cells = ["-" if p[key] is None else f"{p[key]:.3f}" for key in ("accuracy", "precision", "recall", "fp_rate")]
            text += f"| {p['threshold']:g} | " + " | ".join(cells) + " |\n"
    if result.get("calibrated"):
        c = result["calibrated"]
        text += (f"\nLowest threshold with precision >= {c['min_precision']:g} on these cases: "
                 + (f"**{c['threshold']:.4f}** (accuracy {c['accuracy']:.3f}, recall {c['recall']:.3f})\n"
                    if c["threshold"] is not None else "none reaches it\n"))
    return text


def run(args) -> dict:
    verifier = _build(args)
    data = Path(args.data) if getattr(args, "data", None) else heldout_set(args)
    out = Path(args.out) if getattr(args, "out", None) else None
    result = score(verifier, data, k=args.k, limit=getattr(args, "limit", None),
                   errors_png=out.with_name(out.stem + "_errors.png") if out else None,
                   min_precision=getattr(args, "min_precision", None))
    if not getattr(args, "data", None):
        result["heldout"] = ("collected on the spot: fresh init states from the fresh-heldout seed range "
                             "(task_seed + 200000 + j), used by no training collection and no shipped init state")
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(markdown(result))
        result["markdown"] = str(out)
    return result
