"""A full offline annotation run on a small dataset recorded by the scripted expert in the real
LIBERO simulator (libero_10 task 0, init state 0, recorded once per session with the fast
renderer: ~30-40 s on this machine; the synthetic multi-episode runs are in test_annotate.py)."""

from __future__ import annotations

import json
from pathlib import Path

import av
import pytest

from seal.annotate.backends import make_annotator
from seal.annotate.loader import AnnotatedDataset
from seal.annotate.pipeline import RunOptions, annotate_dataset, read_annotations
from seal.annotate.quality import quality_report
from seal.cli import main
from seal.datasets import open_dataset
from seal.demos import record_demos


@pytest.fixture(scope="session")
def expert_dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("expert") / "libero_10_t0"
    summary = record_demos("libero_10", root, episodes_per_task=1, tasks=[0], render_mode="fast")
    assert summary.recorded == 1, summary
    return root


def test_offline_run_on_expert_demos(expert_dataset, tmp_path, capsys):
    reader = open_dataset(expert_dataset)
    out = tmp_path / "ann"
    summary = annotate_dataset(expert_dataset, out, make_annotator("offline"), RunOptions(videos=True))
    assert (summary.annotated, summary.failed) == (1, 0)
    assert 0 < summary.max_tokens <= 415 and summary.over_budget == 0
    records = read_annotations(out)
    report = quality_report(records, reader, 5)
    assert report["agreement"] == 1.0 and report["now_mismatch"] == 0.0 and report["frame_err_p90"] == 0.0

    ds = AnnotatedDataset(out)
    for e in (0,):
        meta, record = reader.episode_meta(e), records[e]
        assert record["plans"] == meta["subplans"] == ["pick up the alphabet soup", "place it in the basket",
                                                       "pick up the tomato sauce", "place it in the basket"]
        # The labels equal what the expert itself wrote each time it thought (it thinks at chunk
        # starts), so a VLA trained on them learns the expert's own reasoning text.
        labels = ds.labels(e)
        reasoning = labels.column("reasoning").to_pylist()
        thoughts = [(s, text) for s, text in meta["meta"]["reasoning"] if s < record["length"]]
        assert len(thoughts) == 4
        for step, text in thoughts:
            assert reasoning[step] == text, (step, reasoning[step], text)
        # The clip is the real agent view at 10 fps.
        with av.open(str(out / record["clip_path"])) as c:
            frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
        assert len(frames) == (record["length"] - 1) // 2 + 1 == len(record["frame_map"]["video_to_dataset"])
        assert 30 < frames[0].mean() < 225 and frames[0].std() > 10  # a rendered scene, not a blank

    assert main(["bench", "annotate", "--dataset", str(expert_dataset), "--backend", "offline"]) == 0
    bench = json.loads(capsys.readouterr().out)
    assert bench["agreement"] == 1.0 and bench["episodes"] == 1 and bench["failed"] == 0
