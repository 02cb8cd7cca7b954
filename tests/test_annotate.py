"""Annotation pipeline without a network: clips, parsing, alignment, tokens, offline runs, resume.

Synthetic LeRobot datasets (tests/_annotate_data.py) in both layouts; the real-simulator run is
in test_annotate_sim.py and the model backends in test_annotate_backends.py.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import av
import numpy as np
import pytest
from _annotate_data import PLANS, make_v21, make_v30

from seal.annotate.align import (
    MARKER_TOKENS,
    Cl100kCounter,
    budget_summary,
    chunk_labels,
    label_at,
    training_sequences,
)
from seal.annotate.backends import make_annotator
from seal.annotate.loader import AnnotatedDataset
from seal.annotate.parse import AnswerError, clean_plan, extract_json, parse_answer
from seal.annotate.pipeline import RunOptions, _OutDir, annotate_dataset, parse_episode_list, read_annotations
from seal.annotate.prompt import build_prompt, retry_message
from seal.annotate.quality import quality_report
from seal.annotate.video import FrameMap, resample, write_clip
from seal.cli import main
from seal.datasets import open_dataset
from seal.errors import InvalidInput
from seal.policies.base import Reasoning

LENGTHS = [63, 48, 57, 40, 52]


@pytest.fixture(scope="module")
def v21(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("v21") / "ds"
    make_v21(root, LENGTHS)
    return root


@pytest.fixture(scope="module")
def v30(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("v30") / "ds"
    make_v30(root, LENGTHS[:3])
    return root


# --------------------------------------------------------------------------- frame mapping


def test_frame_map_at_20_fps():
    fm = FrameMap(dataset_fps=20, length=189)
    assert fm.num_video_frames == 95
    assert [fm.dataset_frame(v) for v in (0, 1, 14, 94)] == [0, 2, 28, 188]
    assert fm.first_showing(28) == 14 and fm.first_showing(29) == 15 and fm.first_showing(188) == 94
    assert fm.time_of(15) == 1.5
    short = FrameMap(dataset_fps=20, length=174)  # last frame 173 is odd: not in the clip
    assert short.num_video_frames == 87 and short.first_showing(173) == 86
    with pytest.raises(InvalidInput, match="valid: 0..94"):
        fm.dataset_frame(95)
    with pytest.raises(InvalidInput, match="outside the episode"):
        fm.first_showing(189)


def test_frame_map_other_rates():
    fm = FrameMap(dataset_fps=15, length=31)  # 2 s at 15 fps -> 21 frames at 10 fps
    assert fm.num_video_frames == 21
    assert fm.dataset_frames()[:5] == [0, 1, 3, 4, 6]
    slow = FrameMap(dataset_fps=5, length=4)  # slower than 10 fps: frames repeat
    assert slow.dataset_frames() == [0, 0, 1, 1, 2, 2, 3]
    for d in range(4):  # first_showing is the inverse wherever a frame is shown
        assert slow.dataset_frame(slow.first_showing(d)) == d
    with pytest.raises(InvalidInput, match="positive integer"):
        FrameMap(dataset_fps=0, length=3)


def test_clip_is_10_fps_mp4_of_the_mapped_frames(tmp_path):
    T = 41
    frames = np.zeros((T, 64, 64, 3), np.uint8)
    for t in range(T):
        frames[t, :, :, 0] = t * 6  # each frame's red level encodes its index
    fm = FrameMap(dataset_fps=20, length=T)
    clip = resample(frames, fm)
    path = write_clip(clip, tmp_path / "clip.mp4")
    with av.open(str(path)) as c:
        stream = c.streams.video[0]
        decoded = [f.to_ndarray(format="rgb24") for f in c.decode(stream)]
        assert float(stream.average_rate) == 10.0
    assert len(decoded) == fm.num_video_frames == 21
    red = [round(d[..., 0].mean() / 6) for d in decoded]
    assert red == fm.dataset_frames()


# --------------------------------------------------------------------------- prompt and parsing


def test_prompt_has_the_template_structure():
    p = build_prompt("put the bowl on the plate.", n_frames=95)
    for needle in ("Task goal: put the bowl on the plate", "task goal alone", "frame = time x 10",
                   "95 frames, numbered 0 to 94", "same length", '"critical_moments"', "nothing else"):
        assert needle in p
    assert "between 0 and 94" in retry_message("bad", 95) and "bad" in retry_message("bad", 95)


GOOD = {"plans": ["pick up the bowl", "place it on the plate"],
        "critical_moments": [{"time": 1.2, "frame": 12}, {"time": 3.0, "frame": 30}]}


@pytest.mark.parametrize("text", [
    json.dumps(GOOD),
    "```json\n" + json.dumps(GOOD, indent=2) + "\n```",
    "Sure! Here is the annotation:\n" + json.dumps(GOOD) + "\nLet me know if you need more.",
    "```\n" + json.dumps(GOOD) + "\n```\nNote: the grasp is at 1.2 s.",
    ('{"plans": ["1. Pick up the bowl.", "2) place it on the plate"], "critical moment": '
     '[{"time": "1.2", "frame": "12"}, {"time": 3.05, "frame": 30.0},]}'),  # seed key, strings, trailing comma
])
def test_lenient_extraction_strict_content(text):
    a = parse_answer(text, FrameMap(20, 80))
    assert [p.lower() for p in a.plans] == ["pick up the bowl", "place it on the plate"]
    assert a.video_frames == [12, 30] and a.dataset_frames == [24, 60]


@pytest.mark.parametrize("obj,message", [
    ({"plans": ["a", "b"], "critical_moments": [{"time": 1.0, "frame": 10}]}, "2 plans but 1 critical moments"),
    ({"plans": ["a"], "critical_moments": [{"time": 9.0, "frame": 90}]}, "outside the video; valid frames are 0 to 39"),
    ({"plans": ["a"], "critical_moments": [{"time": -0.1, "frame": -1}]}, "outside the video"),
    ({"plans": ["a", "b"], "critical_moments": [{"time": 2.0, "frame": 20}, {"time": 1.0, "frame": 10}]},
     "earlier than the previous step"),
    ({"plans": ["a"], "critical_moments": [{"time": 3.5, "frame": 10}]}, "frame 10 is at 1.0 s"),
    ({"plans": ["a"], "critical_moments": [{"time": 1.05, "frame": 10.5}]}, "whole numbers"),
    ({"plans": [], "critical_moments": []}, "non-empty list"),
    ({"plans": ["a", 3], "critical_moments": []}, "plans\\[1\\]"),
    ({"plans": ["a"]}, "no \"critical_moments\" list"),
    ({"plans": ["a"], "critical_moments": [{"frame": 3}]}, "\"time\" and \"frame\""),
    ({"plans": ["a"], "critical_moments": [{"time": True, "frame": 3}]}, "expected a number"),
])
def test_validation_errors_name_the_problem(obj, message):
    with pytest.raises(AnswerError, match=message):
        parse_answer(json.dumps(obj), FrameMap(20, 79))  # 40 video frames


def test_no_json_at_all():
    with pytest.raises(AnswerError, match="no JSON object"):
        extract_json("The robot picks up the bowl at about two seconds.")
    with pytest.raises(AnswerError, match="empty"):
        extract_json("   ")
    assert clean_plan("  Step 2: close   the drawer. ") == "close the drawer"


# --------------------------------------------------------------------------- alignment and tokens


def test_chunk_labels_follow_critical_frames():
    plans = ["pick up the bowl", "place it on the plate", "close the drawer"]
    labels = chunk_labels(plans, [10, 20, 20], length=31, horizon=5)
    assert [lb.frame for lb in labels] == [0, 5, 10, 15, 20, 25, 30]
    assert [lb.reasoning.now for lb in labels] == [plans[0], plans[0], plans[1], plans[1], "", "", ""]
    assert [lb.new_subplan for lb in labels] == [True, False, True, False, True, False, False]
    assert labels[2].text == Reasoning(plans=tuple(plans), done=(plans[0],), now=plans[1]).text()
    assert labels[2].text == ("Plans: 1. pick up the bowl. 2. place it on the plate. 3. close the drawer.\n"
                              "What has been done: pick up the bowl.\nNow I need to do: place it on the plate.")
    assert labels[-1].text.endswith("Now I need to do: the task is complete.")
    # A sub-goal that never held (-1) stays "now" to the end.
    assert label_at(plans, [10, -1, -1], 30).now == plans[1]
    with pytest.raises(InvalidInput, match="2 plans but 3"):
        chunk_labels(plans[:2], [1, 2, 3], 10)


def test_training_sequences_and_token_budget():
    counter = Cl100kCounter()
    assert counter.count("hello world") == 2  # cl100k_base, from the wheel: no download
    labels = chunk_labels(PLANS, [9, 20, 30, 39], length=42)
    seqs = training_sequences("put the bowl and the mug on the plate", labels, 42, counter)
    s = seqs[-1]
    assert s.text.startswith("put the bowl and the mug on the plate\n<think>Plans: 1. pick up the black bowl.")
    assert s.text.endswith("the task is complete.<act>")
    assert (s.action_from, s.action_to) == (40, 42) and (seqs[0].action_from, seqs[0].action_to) == (0, 16)
    reasoning = s.text.split("<think>")[1].removesuffix("<act>")
    assert s.n_tokens == (counter.count("put the bowl and the mug on the plate") + counter.count("\n" + reasoning)
                          + MARKER_TOKENS)
    assert budget_summary(seqs)["over_budget"] == 0 and 40 < budget_summary(seqs)["max_tokens"] < 415
    long = training_sequences("word " * 500, labels, 42, counter)
    assert budget_summary(long)["over_budget"] == len(labels)


# --------------------------------------------------------------------------- offline runs, both layouts


@pytest.mark.parametrize("layout", ["v21", "v30"])
def test_offline_run_reads_both_layouts(layout, request, tmp_path):
    root = request.getfixturevalue(layout)
    reader = open_dataset(root)
    out = tmp_path / "ann"
    summary = annotate_dataset(root, out, make_annotator("offline"), RunOptions(videos=True))
    assert (summary.annotated, summary.failed) == (reader.num_episodes, 0)
    records = read_annotations(out)
    assert sorted(records) == list(range(reader.num_episodes))
    report = quality_report(records, reader, 5)
    assert report["agreement"] == 1.0 and report["plan_count_agreement"] == 1.0
    assert report["frame_err_mean"] == 0.0 and report["now_mismatch"] == 0.0

    ds = AnnotatedDataset(out)
    for e in ds.episodes:
        rec, meta = records[e], reader.episode_meta(e)
        assert rec["instruction"] == meta["tasks"][0]
        assert [m["dataset_frame"] for m in rec["critical_moments"]] == list(meta["critical_frames"])
        fm = rec["frame_map"]
        assert fm["video_to_dataset"] == FrameMap(20, rec["length"]).dataset_frames()
        with av.open(str(out / rec["clip_path"])) as c:
            assert sum(1 for _ in c.decode(video=0)) == len(fm["video_to_dataset"])
        labels = ds.labels(e)
        assert labels.num_rows == rec["length"]
        truth = chunk_labels(meta["subplans"], meta["critical_frames"], rec["length"])
        starts = labels.filter(labels.column("is_chunk_start")).column("reasoning").to_pylist()
        assert starts == [lb.text for lb in truth]
    sample = ds.sample(1, 23)
    actions = reader.episode(1).actions
    assert sample["chunk_start"] == 20
    np.testing.assert_array_equal(sample["actions"], actions[20:36])
    assert "<think>" in sample["sequence"] and sample["reasoning"] in sample["sequence"]
    if layout == "v30":  # global index column joins labels to the source rows
        assert ds.labels(1).column("index").to_pylist()[0] == LENGTHS[0]


def test_offline_without_ground_truth_fails_loudly(tmp_path, v21):
    # Episode 2 of a copy loses its recorded sub-plans: it is recorded as failed, not dropped.
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(v21, root)
    path = root / "meta/episodes.jsonl"
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    lines[2]["subplans"], lines[2]["critical_frames"] = [], []
    lines[3]["critical_frames"][3] = -1
    path.write_text("".join(json.dumps(x) + "\n" for x in lines))
    out = tmp_path / "ann"
    summary = annotate_dataset(root, out, make_annotator("offline"))
    assert (summary.annotated, summary.failed) == (3, 2)
    records = read_annotations(out)
    assert records[2]["status"] == "failed" and "no recorded sub-plans" in records[2]["error"]
    assert records[3]["status"] == "failed" and "never held" in records[3]["error"]
    # A re-run skips them; --retry-failed redoes them, still one line per episode.
    assert annotate_dataset(root, out, make_annotator("offline")).skipped == 5
    again = annotate_dataset(root, out, make_annotator("offline"), RunOptions(retry_failed=True))
    assert (again.skipped, again.failed) == (3, 2)
    lines = (out / "annotations.jsonl").read_text().splitlines()
    assert sorted(json.loads(x)["episode_index"] for x in lines) == [0, 1, 2, 3, 4]


# --------------------------------------------------------------------------- resume


class Interrupt(KeyboardInterrupt):
    pass


def test_resume_after_interrupt_and_torn_line(tmp_path, v21):
    out = tmp_path / "ann"
    seen = []

    def stop_after_two(record, summary):
        seen.append(record["episode_index"])
        if len(seen) == 2:
            raise Interrupt  # Ctrl-C right after the second commit

    with pytest.raises(KeyboardInterrupt):
        annotate_dataset(v21, out, make_annotator("offline"), RunOptions(concurrency=1), progress=stop_after_two)
    assert sorted(read_annotations(out)) == sorted(seen) == [0, 1]
    assert not (out / "data/chunk-000/episode_000002.parquet").exists()

    # A crash in the middle of appending the third record leaves a torn last line.
    with open(out / "annotations.jsonl", "a") as f:
        f.write('{"episode_index": 2, "status": "ok", "pla')
    summary = annotate_dataset(v21, out, make_annotator("offline"))
    assert (summary.skipped, summary.annotated) == (2, 3)
    lines = [json.loads(x) for x in (out / "annotations.jsonl").read_text().splitlines()]
    assert sorted(r["episode_index"] for r in lines) == [0, 1, 2, 3, 4]  # none lost, none twice
    assert all(r["status"] == "ok" for r in lines)
    assert annotate_dataset(v21, out, make_annotator("offline")).skipped == 5


def test_out_dir_guards(tmp_path, v21):
    out = tmp_path / "ann"
    annotate_dataset(v21, out, make_annotator("offline"), RunOptions(episodes=[0]))
    info = json.loads((out / "annotate_info.json").read_text())
    with pytest.raises(InvalidInput, match="another `seal annotate` run"):
        held = _OutDir(out, info)
        try:
            annotate_dataset(v21, out, make_annotator("offline"))
        finally:
            held.close()
    other = dict(info, model="gpt-4o", backend="openai")
    with pytest.raises(InvalidInput, match="annotations of another run"):
        _OutDir(out, other)
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk/file.txt").write_text("x")
    with pytest.raises(InvalidInput, match="not empty"):
        annotate_dataset(v21, tmp_path / "junk", make_annotator("offline"))
    with pytest.raises(InvalidInput, match="out of range"):
        annotate_dataset(v21, out, make_annotator("offline"), RunOptions(episodes=[7]))


def test_episode_selection():
    assert parse_episode_list("0, 3,5-7", 10) == [0, 3, 5, 6, 7]
    with pytest.raises(InvalidInput, match="out of range"):
        parse_episode_list("9-11", 10)
    with pytest.raises(InvalidInput, match="bad episode selection"):
        parse_episode_list("two", 10)
    with pytest.raises(InvalidInput, match="unknown annotation backend 'claude'"):
        make_annotator("claude")


def test_cli_annotate_and_bench(tmp_path, v21, capsys):
    out = tmp_path / "ann"
    assert main(["annotate", str(v21), "--backend", "offline", "--out", str(out), "--episodes", "0-2"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["annotated"] == 3 and result["quality"]["agreement"] == 1.0
    assert main(["annotate", str(v21), "--backend", "offline", "--out", str(out)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert (result["skipped"], result["annotated"]) == (3, 2)
    assert main(["annotate", str(v21), "--backend", "offline", "--out", str(out), "--episodes", "12"]) == 2
    assert "out of range" in capsys.readouterr().err

    assert main(["bench", "annotate", "--dataset", str(v21), "--backend", "offline"]) == 0
    bench = json.loads(capsys.readouterr().out)
    assert bench["agreement"] == 1.0 and bench["episodes"] == 5 and bench["episodes_per_s"] > 0
    for key in ("plan_count_agreement", "frame_err_mean", "frame_err_p90"):
        assert key in bench


def test_image_features_stored_in_parquet(tmp_path):
    """LeRobot datasets may keep frames as PNG bytes in the parquet rows instead of mp4."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from PIL import Image

    from seal.annotate.video import camera_key, load_frames

    root = tmp_path / "img"
    episodes = make_v30(root, [12, 9])
    data = root / "data/chunk-000/file-000.parquet"
    table = pq.read_table(data)
    frames = np.concatenate([e.agent_images[:, ::4, ::4] for e in episodes])  # 56x56, lossless PNG

    def png(a):
        buf = io.BytesIO()
        Image.fromarray(a).save(buf, format="PNG")
        return {"bytes": buf.getvalue(), "path": None}

    table = table.append_column("front", pa.array([png(a) for a in frames]))
    pq.write_table(table, data)
    info = json.loads((root / "meta/info.json").read_text())
    info["features"]["front"] = {"dtype": "image", "shape": [56, 56, 3]}
    (root / "meta/info.json").write_text(json.dumps(info))
    reader = open_dataset(root)
    np.testing.assert_array_equal(load_frames(reader, 1, "front"), frames[12:])
    assert camera_key(reader) == "observation.images.image"  # our agent view wins
    with pytest.raises(InvalidInput, match="no camera 'side'"):
        camera_key(reader, "side")
    # Without our key: the one non-wrist camera; with two candidates: ask.
    other = dict(info, features={k: v for k, v in info["features"].items() if k != "observation.images.image"})
    reader.info = other
    assert camera_key(reader) == "front"
    reader.info = dict(other, features={**other["features"], "side": {"dtype": "video"}})
    with pytest.raises(InvalidInput, match="which camera"):
        camera_key(reader)
    reader = open_dataset(root)
    summary = annotate_dataset(root, tmp_path / "ann", make_annotator("offline"),
                               RunOptions(camera="front", videos=True))
    assert summary.annotated == 2
    with av.open(str(tmp_path / "ann/videos/episode_000001.mp4")) as c:
        assert c.streams.video[0].codec_context.width == 56


def test_damaged_episode_fails_alone(tmp_path, v21):
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(v21, root)
    (root / "videos/chunk-000/observation.images.image/episode_000001.mp4").unlink()
    out = tmp_path / "ann"
    summary = annotate_dataset(root, out, make_annotator("offline"), RunOptions(videos=True))
    assert (summary.annotated, summary.failed) == (4, 1)
    record = read_annotations(out)[1]
    assert record["status"] == "failed" and "episode_000001.mp4 is missing" in record["error"]
