"""Read an annotation sidecar back, joined with the dataset it annotates (LeRobot-style access).

    ds = AnnotatedDataset("runs/ann")          # opens the source dataset named in annotate_info.json
    ds.episodes                                 # annotated episode indices
    ds.labels(3)                                # pyarrow table: one row per frame of episode 3
    ds.sample(3, 40)                            # the training item whose chunk contains frame 40

The label parquet files are plain LeRobot-style per-episode files, so
``pyarrow.dataset.dataset(OUT / "data")`` or Hugging Face ``datasets.load_dataset("parquet",
data_dir=OUT / "data")`` read them too; join them with the source rows on ``index``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from seal.annotate.pipeline import INFO, read_annotations
from seal.datasets.lerobot import ACTION_KEY, fixed_list_to_numpy, open_dataset
from seal.errors import InvalidInput


class AnnotatedDataset:
    def __init__(self, out: Path, source: Path | None = None):
        self.root = Path(out)
        info_path = self.root / INFO
        if not info_path.is_file():
            raise InvalidInput(f"{self.root} is not an annotation directory: it has no {INFO}")
        self.info = json.loads(info_path.read_text())
        # The source may have moved since annotating: an explicit path wins.
        self.source = open_dataset(Path(source) if source is not None else Path(self.info["source"]))
        self.records = read_annotations(self.root)

    @property
    def episodes(self) -> list[int]:
        return sorted(e for e, r in self.records.items() if r["status"] == "ok")

    def record(self, episode: int) -> dict:
        if episode not in self.records:
            raise InvalidInput(f"episode {episode} is not annotated in {self.root}; annotated: {self.episodes}")
        return self.records[episode]

    def labels(self, episode: int) -> pa.Table:
        record = self.record(episode)
        if record["status"] != "ok":
            raise InvalidInput(f"episode {episode} failed to annotate ({record['error']}); it has no labels")
        return pq.read_table(self.root / record["labels_path"])

    def sample(self, episode: int, frame: int) -> dict:
        """Instruction, reasoning label, training text and the chunk's actions for one frame."""
        table = self.labels(episode)
        if not 0 <= frame < table.num_rows:
            raise InvalidInput(f"frame {frame} is outside episode {episode} (0..{table.num_rows - 1})")
        row = table.slice(frame, 1).to_pylist()[0]
        actions = fixed_list_to_numpy(self.source.frames(episode).column(ACTION_KEY))
        return {
            "episode_index": episode,
            "frame_index": frame,
            "chunk_start": row["chunk_start"],
            "instruction": self.record(episode)["instruction"],
            "reasoning": row["reasoning"],
            "sequence": row["sequence"],
            "n_tokens": row["n_tokens"],
            "actions": np.asarray(actions[row["action_from"]:row["action_to"]]),
        }
