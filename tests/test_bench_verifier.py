"""`seal bench verifier` on recorded cases: the VLM paths against a local OpenAI-/Gemini-compatible
server (answers cached: a second run sends nothing), the oracle and the noisy oracle; and the
case layout itself (no simulator)."""

from __future__ import annotations

import json

import pytest
from PIL import Image

from _local_http import scrub_env, serving
from _verifier_cases import make_row
from test_vlm_verifier import BAD, GEMINI_PATH, KEY, FakeServer, Reply, _make_handler

from seal.cli import main
from seal.errors import InvalidInput
from seal.verify import dataset as ds
from seal.vlm import PRICES_PER_MTOK

LABELS = [True, False, True, False, False, True]  # 3 successes, 3 failures


@pytest.fixture
def server(monkeypatch):
    scrub_env(monkeypatch)
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    monkeypatch.setenv("GOOGLE_API_KEY", KEY)
    fake = FakeServer(url="")
    with serving(fake, _make_handler(fake)):
        yield fake


@pytest.fixture
def cases(tmp_path):
    rows = [make_row(i, label=label) for i, label in enumerate(LABELS)]
    ds.write_shard(tmp_path / "cases", ds.shard_name("libero_10", 0, 0), rows)
    ds.write_info(tmp_path / "cases", {"collection": {}})
    return tmp_path / "cases"


def _bench(capsys, *argv) -> dict:
    assert main(["bench", "verifier", *argv]) == 0
    return json.loads(capsys.readouterr().out)


def test_openai_scored_against_truth_and_never_paid_twice(server, cases, tmp_path, capsys):
    args = ["--verifier", "openai", "--base-url", f"{server.url}/v1", "--data", str(cases),
            "--cache-dir", str(tmp_path / "cache"), "--out", str(tmp_path / "openai.md")]
    first = _bench(capsys, *args)  # the server answers "Success" to everything
    assert server.calls == 6 and all(path == "/v1/chat/completions" for path, _, _ in server.requests)
    assert first["confusion"] == {"tp": 3, "fp": 3, "fn": 0, "tn": 0}
    assert first["precision"] == 0.5 and first["recall"] == 1.0 and first["fp_rate"] == 1.0
    assert first["per_kind"]["pick"]["n"] == 6
    assert first["per_task"]["libero_10/0"]["confusion"] == first["confusion"]
    assert first["input_tokens"] == 6 * 1200 and first["output_tokens"] == 6 * 80
    pin, pout = PRICES_PER_MTOK["gpt-4o"]
    assert first["cost_usd"] == pytest.approx(6 * (1200 * pin + 80 * pout) / 1e6)
    assert "| all | 6 |" in (tmp_path / "openai.md").read_text()
    # beside the table, the three false successes as a contact sheet: three images per case
    sheet = first["error_sheet"]
    assert sheet == {"path": str(tmp_path / "openai_errors.png"), "shown": 3}
    assert Image.open(sheet["path"]).size == (3 * 160, 3 * (160 + 28))

    again = _bench(capsys, *args)
    assert server.calls == 6  # every answer came from the cache
    assert again["cached"] == 6 and again["cost_usd"] == 0 and again["input_tokens"] == 0
    assert again["cost_usd_uncached"] == pytest.approx(first["cost_usd"])
    assert again["confusion"] == first["confusion"]


def test_gemini_path_and_failure_answers(server, cases, tmp_path, capsys):
    server.default = Reply(BAD)
    result = _bench(capsys, "--verifier", "gemini", "--base-url", server.url, "--data", str(cases),
                    "--cache-dir", str(tmp_path / "cache"), "--k", "3")
    assert server.calls == 6 and all(GEMINI_PATH.match(path) for path, _, _ in server.requests)
    assert result["confusion"] == {"tp": 0, "fp": 0, "fn": 3, "tn": 3} and result["fn_rate"] == 1.0
    assert result["output_tokens"] == 6 * (80 + 30)  # thinking tokens are billed as output


def test_oracle_and_noisy_on_recorded_truth(cases, capsys):
    oracle = _bench(capsys, "--verifier", "oracle", "--data", str(cases))
    assert oracle["accuracy"] == 1.0 and oracle["unknown"] == 0
    noisy = _bench(capsys, "--verifier", "noisy", "--false-positive", "1", "--data", str(cases))
    assert noisy["confusion"] == {"tp": 3, "fp": 3, "fn": 0, "tn": 0}
    with pytest.raises(InvalidInput, match="false-positive"):
        from seal.benchmarks.verifier import run
        from argparse import Namespace

        run(Namespace(verifier="noisy", data=str(cases), k=10, false_positive=None, false_negative=None))


def test_per_task_table_names_where_the_mistakes_are(tmp_path, capsys):
    from _verifier_cases import write_cases

    data = write_cases(tmp_path / "cases", 6, tasks=("libero_10/0", "libero_10/2"), inits=2)
    labels: dict[str, list[bool]] = {}
    for c in ds.iter_cases(data):
        labels.setdefault(c.row["task"], []).append(c.label)
    result = _bench(capsys, "--verifier", "noisy", "--false-positive", "1", "--data", str(data),
                    "--out", str(tmp_path / "t.md"))
    for task, truth in labels.items():  # every failure called a success, task by task
        assert result["per_task"][task]["confusion"] == {"tp": sum(truth), "fp": len(truth) - sum(truth),
                                                         "fn": 0, "tn": 0}
    table = (tmp_path / "t.md").read_text().split("By task:")[1]
    assert "| libero_10/0 | 6 |" in table and "| libero_10/2 | 6 |" in table


def test_case_layout_round_trip_and_torn_writes(cases):
    (cases / "data" / ".shard-libero_10-000-00009.parquet.tmp").write_bytes(b"PAR1 half a file")
    table = ds.read_cases(cases)
    assert table.num_rows == 6 and table.schema == ds.arrow_schema()
    case = next(ds.iter_cases(cases, limit=1))
    assert all(img.shape == (224, 224, 3) for img in case.images)
    req = ds.to_request(case)
    assert req.scene.facts == dict(zip(case.row["atoms"], case.row["atom_values"]))
    info = json.loads((cases / "info.json").read_text())
    assert set(info["columns"]) == set(ds.COLUMNS) and info["image_size"] == 224
    (cases / "info.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(InvalidInput, match="not a seal-verification-cases"):
        ds.read_cases(cases)


@pytest.mark.parametrize("subplan,atoms,kind", [
    ("pick up the alphabet soup", ["Grasped(alphabet_soup_1)"], "pick"),
    ("place it in the basket", ["In(alphabet_soup_1, basket_1_contain_region)"], "place"),
    ("put the mug on the plate", ["On(red_coffee_mug_1, plate_1)"], "place"),
    ("open the top drawer of the cabinet", ["Open(wooden_cabinet_1_top_region)"], "open"),
    ("close the microwave", ["Close(microwave_1)"], "close"),
    ("turn on the stove", ["TurnOn(flat_stove_1)"], "turn"),
    ("switch off the burner", [], "turn"),
    ("grab the bowl", [], "pick"),
    ("shut the door", [], "close"),
    ("wipe the table", [], "other"),
])
def test_subplan_kinds(subplan, atoms, kind):
    assert ds.subplan_kind(subplan, atoms) == kind


def test_binary_metrics():
    m = ds.binary_metrics([True, True, False, False, False], [True, False, True, False, False])
    assert m["confusion"] == {"tp": 1, "fp": 1, "fn": 1, "tn": 2}
    assert m["accuracy"] == 0.6 and m["precision"] == 0.5 and m["recall"] == 0.5 and m["f1"] == 0.5
    assert m["fp_rate"] == pytest.approx(1 / 3, abs=1e-4) and m["fn_rate"] == 0.5


def test_intervals_resample_start_states_not_cases():
    from seal.benchmarks.verifier import start_intervals

    # 400 cases, 200 right: once as 20 starts whose 20 cases are all right or all wrong, once as 400
    # independent starts. Same accuracy; the clustered set knows far less about it.
    labels = [True] * 400
    predicted = [i < 200 for i in range(400)]
    clustered = start_intervals(labels, predicted, [i // 20 for i in range(400)])
    independent = start_intervals(labels, predicted, list(range(400)))
    assert clustered["starts"] == 20 and independent["starts"] == 400
    for ci in (clustered, independent):
        assert ci["accuracy"][0] < 0.5 < ci["accuracy"][1]
    assert clustered["accuracy"][1] - clustered["accuracy"][0] > 0.35  # ~ +-0.22 for 10 of 20 starts
    assert independent["accuracy"][1] - independent["accuracy"][0] < 0.12  # ~ +-0.05 for 200 of 400 cases
    assert clustered["precision"] == [1.0, 1.0]  # no false success in any resample
    assert start_intervals(labels, predicted, [i // 20 for i in range(400)]) == clustered  # seeded


def test_bench_reports_intervals_over_start_states(cases, capsys):
    out = _bench(capsys, "--verifier", "noisy", "--false-positive", "1", "--data", str(cases))
    rows = ds.read_cases(cases, ["task", "init_source", "init_index"]).to_pylist()
    starts = {ds.init_key_of(r["task"], r["init_source"], r["init_index"]) for r in rows}
    assert out["ci95"]["starts"] == len(starts) and out["ci95"]["by"] == "start state"
    assert out["ci95"]["accuracy"][0] <= out["accuracy"] <= out["ci95"]["accuracy"][1]
