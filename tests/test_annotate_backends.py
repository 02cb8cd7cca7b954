"""The Gemini and OpenAI-compatible annotators with their real SDK clients against a local server.

The server (stdlib ``http.server`` on 127.0.0.1, started per test) speaks
``POST /v1/chat/completions`` (OpenAI), the Gemini Files API (resumable upload start and
finalize, ``GET``/``DELETE /v1beta/files/{id}``) and ``POST /v1beta/models/{m}:generateContent``.
Each test scripts its replies; the server records every request and the peak in flight.
"""

from __future__ import annotations

import asyncio
import base64
import io
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler
from pathlib import Path
from urllib.parse import urlparse

import av
import numpy as np
import pytest
from PIL import Image

from _annotate_data import PLANS, make_v21
from _local_http import scrub_env, serving

from seal.annotate.backends import AnnotatorCallError, EpisodeInput, make_annotator
from seal.annotate.pipeline import RunOptions, annotate_dataset, read_annotations
from seal.annotate.quality import quality_report
from seal.annotate.video import FrameMap, resample, write_clip
from seal.datasets import open_dataset
from seal.errors import InvalidInput

KEY = "sk-annotate-test-5e1d-DO-NOT-LEAK"
GEN = re.compile(r"^/v1(?:beta)?/models/([^/:]+):generateContent$")
FILE = re.compile(r"^/v1(?:beta)?/files/([^/?]+)$")
UPLOAD = re.compile(r"^/upload/v1(?:beta)?/files$")
N_FRAMES = re.compile(r"The video has (\d+) frames")


def valid_answer(n: int, plans=("pick up the bowl", "place it on the plate")) -> str:
    frames = [round((k + 1) * (n - 1) / len(plans)) for k in range(len(plans))]
    return json.dumps({"plans": list(plans), "critical_moments": [{"time": f / 10, "frame": f} for f in frames]})


def answer_from_prompt(body: dict) -> str:
    """A well-formed answer sized to whatever clip the request describes."""
    n = int(N_FRAMES.search(json.dumps(body)).group(1))
    return valid_answer(n, plans=PLANS)


@dataclass
class Reply:
    text: str | Callable[[dict], str] = answer_from_prompt
    status: int = 200
    hang: bool = False
    delay_s: float = 0.0
    usage: tuple[int, int] = (5000, 120)


@dataclass
class Server:
    url: str = ""
    requests: list = field(default_factory=list)  # (method, path, headers, body)
    script: list = field(default_factory=list)
    default: Reply = field(default_factory=Reply)
    uploads: dict = field(default_factory=dict)  # file id -> bytes
    deleted: list = field(default_factory=list)
    file_states: list = field(default_factory=lambda: ["PROCESSING", "ACTIVE"])  # upload, then each GET
    in_flight: int = 0
    peak_in_flight: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    release: threading.Event = field(default_factory=threading.Event)

    def next_reply(self) -> Reply:
        with self.lock:
            return self.script.pop(0) if self.script else self.default

    def calls(self, kind: str) -> list:
        pattern = {"openai": re.compile(r"^/v1/chat/completions$"), "gemini": GEN}[kind]
        return [r for r in self.requests if pattern.match(r[1])]


def _file_json(server: Server, fid: str, state: str) -> dict:
    return {"name": f"files/{fid}", "uri": f"{server.url}/v1beta/files/{fid}", "mimeType": "video/mp4",
            "sizeBytes": str(len(server.uploads.get(fid, b""))), "state": state}


def _handler(server: Server):
    class H(BaseHTTPRequestHandler):
        def _body(self) -> bytes:
            return self.rfile.read(int(self.headers.get("content-length", 0) or 0))

        def _record(self, method, body):
            with server.lock:
                server.requests.append((method, urlparse(self.path).path,
                                        {k.lower(): v for k, v in self.headers.items()}, body))

        def do_POST(self):
            raw = self._body()
            path = urlparse(self.path).path
            if UPLOAD.match(path) and "upload_id" not in self.path:
                self._record("POST", json.loads(raw or b"{}"))
                fid = f"f{len(server.uploads) + 1}"
                server.uploads[fid] = b""
                return self._send(200, {}, {"x-goog-upload-url": f"{server.url}/upload/v1beta/files?upload_id={fid}"})
            if UPLOAD.match(path):
                fid = self.path.split("upload_id=")[1]
                server.uploads[fid] += raw
                self._record("UPLOAD", {"bytes": len(raw), "command": self.headers.get("x-goog-upload-command")})
                state = server.file_states[0]
                return self._send(200, {"file": _file_json(server, fid, state)}, {"x-goog-upload-status": "final"})
            body = json.loads(raw or b"{}")
            gemini = GEN.match(path)
            if path != "/v1/chat/completions" and not gemini:
                return self._send(404, {"error": {"message": f"no route {path}"}})
            self._record("POST", body)
            with server.lock:
                server.in_flight += 1
                server.peak_in_flight = max(server.peak_in_flight, server.in_flight)
            try:
                reply = server.next_reply()
                if reply.hang:
                    server.release.wait(timeout=20)
                    return
                time.sleep(reply.delay_s)
                if reply.status != 200:
                    err = {"error": {"code": reply.status, "message": f"scripted {reply.status}",
                                     "status": "UNAVAILABLE"}}
                    return self._send(reply.status, err)
                text = reply.text(body) if callable(reply.text) else reply.text
                if gemini:
                    out = {"candidates": [{"content": {"role": "model", "parts": [{"text": text}]},
                                           "finishReason": "STOP", "index": 0}],
                           "usageMetadata": {"promptTokenCount": reply.usage[0],
                                             "candidatesTokenCount": reply.usage[1], "thoughtsTokenCount": 40,
                                             "totalTokenCount": sum(reply.usage) + 40}}
                else:
                    out = {"id": "x", "object": "chat.completion", "created": 0, "model": body.get("model", ""),
                           "choices": [{"index": 0, "message": {"role": "assistant", "content": text},
                                        "finish_reason": "stop"}],
                           "usage": {"prompt_tokens": reply.usage[0], "completion_tokens": reply.usage[1],
                                     "total_tokens": sum(reply.usage)}}
                self._send(200, out)
            finally:
                with server.lock:
                    server.in_flight -= 1

        def do_GET(self):
            m = FILE.match(urlparse(self.path).path)
            if not m:
                return self._send(404, {"error": {"message": "no route"}})
            self._record("GET", {})
            states = server.file_states
            state = states[min(1 + sum(r[0] == "GET" for r in server.requests) - 1, len(states) - 1)]
            self._send(200, _file_json(server, m.group(1), state))

        def do_DELETE(self):
            m = FILE.match(urlparse(self.path).path)
            self._record("DELETE", {})
            server.deleted.append(m.group(1) if m else self.path)
            self._send(200, {})

        def _send(self, status, payload, headers=None):
            data = json.dumps(payload).encode()
            try:
                self.send_response(status)
                self.send_header("content-type", "application/json")
                self.send_header("content-length", str(len(data)))
                for k, v in (headers or {}).items():
                    self.send_header(k, v)
                self.end_headers()
                self.wfile.write(data)
            except (BrokenPipeError, ConnectionResetError):
                pass

        def log_message(self, *args):
            pass

    return H


@pytest.fixture
def server():
    fake = Server()
    with serving(fake, _handler(fake)):
        yield fake


@pytest.fixture(autouse=True)
def clean_env(monkeypatch):
    scrub_env(monkeypatch)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ds") / "ds"
    make_v21(root, [44, 38, 50, 36])
    return root


def _job(tmp_path: Path, T: int = 40, seed: int = 0) -> EpisodeInput:
    rng = np.random.default_rng(seed)
    frames = np.repeat(rng.integers(0, 256, (T, 1, 1, 3), dtype=np.uint8), 32, axis=1).repeat(32, axis=2)
    fm = FrameMap(dataset_fps=20, length=T)
    clip = resample(frames, fm)
    path = write_clip(clip, tmp_path / f"clip{seed}.mp4")
    return EpisodeInput(episode=seed, instruction="put the bowl on the plate", frame_map=fm, clip=clip,
                        clip_path=path)


def _openai(server, **opts):
    opts.setdefault("api_key", KEY)
    opts.setdefault("backoff_s", 0.01)
    opts.setdefault("timeout_s", 5.0)
    return make_annotator("openai", base_url=f"{server.url}/v1", **opts)


def _gemini(server, **opts):
    opts.setdefault("api_key", KEY)
    opts.setdefault("backoff_s", 0.01)
    opts.setdefault("timeout_s", 5.0)
    opts.setdefault("poll_s", 0.01)
    return make_annotator("gemini", base_url=server.url, **opts)


def _annotate(annotator, job):
    async def go():
        try:
            return await annotator.annotate(job)
        finally:
            await annotator.aclose()

    return asyncio.run(go())


def _texts(message_content) -> list[str]:
    return [p["text"] for p in message_content if p.get("type") == "text"]


# --------------------------------------------------------------------------- openai


def test_openai_frames_as_images_and_valid_answer(server, tmp_path):
    job = _job(tmp_path)  # 40 dataset frames at 20 fps -> 20 clip frames
    result = _annotate(_openai(server, image_format="png"), job)
    assert result.status == "ok", result.error
    assert result.annotation.video_frames == [5, 10, 14, 19]
    assert result.annotation.dataset_frames == [10, 20, 28, 38]
    [(_, _, headers, body)] = server.calls("openai")
    assert headers["authorization"] == f"Bearer {KEY}" and body["model"] == "gpt-4o"
    [message] = body["messages"]
    content = message["content"]
    assert "Task goal: put the bowl on the plate" in content[0]["text"] and "20 frames" in content[0]["text"]
    assert _texts(content)[1:4] == ["Frame 0 (time 0.0 s):", "Frame 1 (time 0.1 s):", "Frame 2 (time 0.2 s):"]
    urls = [p["image_url"]["url"] for p in content if p["type"] == "image_url"]
    assert len(urls) == 20
    for v in (0, 7, 19):  # PNG: the exact clip pixels, in order
        data = base64.b64decode(urls[v].split(",", 1)[1])
        np.testing.assert_array_equal(np.asarray(Image.open(io.BytesIO(data))), job.clip[v])
    assert result.calls[0]["input_tokens"] == 5000 and result.calls[0]["cost_usd"] == pytest.approx(
        (5000 * 2.5 + 120 * 10.0) / 1e6)


def test_openai_frame_stride_keeps_true_numbers(server, tmp_path):
    _annotate(_openai(server, frame_stride=5), _job(tmp_path))
    content = server.calls("openai")[0][3]["messages"][0]["content"]
    assert _texts(content)[1:] == [f"Frame {v} (time {v / 10:.1f} s):" for v in (0, 5, 10, 15)]


def test_malformed_json_is_fed_back_then_accepted(server, tmp_path):
    server.script = [Reply("The bowl is picked at 1 s and placed at 2 s."), Reply()]
    result = _annotate(_openai(server), _job(tmp_path))
    assert result.status == "ok" and len(result.raw) == 2
    second = server.calls("openai")[1][3]["messages"]
    assert [m["role"] for m in second] == ["user", "assistant", "user"]
    assert second[1]["content"] == "The bowl is picked at 1 s and placed at 2 s."
    assert "no JSON object found" in second[2]["content"] and "between 0 and 19" in second[2]["content"]
    assert result.calls[0]["outcome"].startswith("invalid: no JSON")


def test_mismatched_lengths_fail_after_n_retries_with_raw_kept(server, tmp_path):
    bad = json.dumps({"plans": ["a", "b", "c"], "critical_moments": [{"time": 1.0, "frame": 10}]})
    server.default = Reply(bad)
    result = _annotate(_openai(server, max_invalid=2), _job(tmp_path))
    assert result.status == "failed" and result.annotation is None
    assert len(server.calls("openai")) == 3 and result.raw == [bad] * 3
    assert "3 plans but 1 critical moments" in result.error and "after 3 replies" in result.error
    assert result.input_tokens == 3 * 5000  # every reply was paid for and is counted


def test_out_of_range_frames_are_corrected(server, tmp_path):
    wrong = json.dumps({"plans": ["a"], "critical_moments": [{"time": 50.0, "frame": 500}]})
    server.script = [Reply(wrong), Reply()]
    result = _annotate(_openai(server), _job(tmp_path))
    assert result.status == "ok"
    feedback = server.calls("openai")[1][3]["messages"][2]["content"]
    assert "frame is 500, outside the video; valid frames are 0 to 19" in feedback


def test_timeouts_and_transient_errors(server, tmp_path):
    server.default = Reply(hang=True)
    started = time.perf_counter()
    result = _annotate(_openai(server, timeout_s=0.5, max_retries=1), _job(tmp_path))
    assert time.perf_counter() - started < 3.0
    assert result.status == "failed" and "timed out after 0.5 s" in result.error
    assert len(server.calls("openai")) == 2

    server.requests.clear()
    server.default = Reply()
    server.script = [Reply(status=429), Reply(status=503)]
    result = _annotate(_openai(server, max_retries=3), _job(tmp_path))
    assert result.status == "ok" and len(server.calls("openai")) == 3
    assert [c["outcome"].split(":")[0] for c in result.calls] == ["error", "error", "reply"]


def test_rejected_key_stops_without_leaking(server, tmp_path):
    server.default = Reply(status=401)
    with pytest.raises(AnnotatorCallError, match="401") as info:
        _annotate(_openai(server), _job(tmp_path))
    assert KEY not in str(info.value) and len(server.calls("openai")) == 1


def test_cache_hit_skips_the_server(server, tmp_path):
    cache = tmp_path / "cache"
    first = _annotate(_openai(server, cache_dir=cache), _job(tmp_path))
    second = _annotate(_openai(server, cache_dir=cache), _job(tmp_path))
    assert len(server.calls("openai")) == 1
    assert second.cached and second.annotation == first.annotation and second.cost_usd == 0
    _annotate(_openai(server, cache_dir=cache, model="gpt-4o-mini"), _job(tmp_path))
    _annotate(_openai(server, cache_dir=cache), _job(tmp_path, seed=1))  # other pixels
    assert len(server.calls("openai")) == 3


def test_openai_from_environment_only(server, tmp_path, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    monkeypatch.setenv("OPENAI_BASE_URL", f"{server.url}/v1")
    result = _annotate(make_annotator("openai"), _job(tmp_path))
    assert result.status == "ok"
    assert server.calls("openai")[0][2]["authorization"] == f"Bearer {KEY}"
    monkeypatch.delenv("OPENAI_API_KEY")
    with pytest.raises(InvalidInput, match="OPENAI_API_KEY"):
        make_annotator("openai")


# --------------------------------------------------------------------------- gemini


def test_gemini_uploads_the_clip_and_annotates(server, tmp_path):
    job = _job(tmp_path)
    result = _annotate(_gemini(server), job)
    assert result.status == "ok", result.error
    assert result.annotation.dataset_frames == [10, 20, 28, 38]
    [fid] = server.uploads
    with av.open(io.BytesIO(server.uploads[fid])) as c:  # the bytes uploaded are the 10 fps clip
        stream = c.streams.video[0]
        assert float(stream.average_rate) == 10.0 and sum(1 for _ in c.decode(stream)) == 20
    assert any(r[0] == "GET" for r in server.requests)  # waited for PROCESSING -> ACTIVE
    [(_, path, headers, body)] = server.calls("gemini")
    assert GEN.match(path).group(1) == "gemini-2.5-pro" and headers["x-goog-api-key"] == KEY
    parts = body["contents"][0]["parts"]
    video = parts[0]
    file_data = video.get("fileData") or video.get("file_data")
    assert file_data["fileUri"if "fileUri" in file_data else "file_uri"].endswith(f"/files/{fid}")
    assert (video.get("videoMetadata") or video.get("video_metadata"))["fps"] == 10
    assert "20 frames" in parts[1]["text"]
    assert body["generationConfig"]["responseMimeType"] == "application/json"
    assert server.deleted == [fid]  # cleaned up
    assert result.output_tokens == 120 + 40  # thinking tokens are billed as output
    assert result.cost_usd == pytest.approx((5000 * 1.25 + 160 * 10.0) / 1e6)


def test_gemini_invalid_answers_then_failure_keeps_raw(server, tmp_path):
    out_of_range = json.dumps({"plans": ["a"], "critical_moments": [{"time": 9.9, "frame": 99}]})
    fenced_mismatch = "```json\n" + json.dumps({"plans": ["a", "b"], "critical_moments": []}) + "\n```"
    server.default = Reply(out_of_range)
    server.script = [Reply("not json at all"), Reply(fenced_mismatch)]
    result = _annotate(_gemini(server, max_invalid=2), _job(tmp_path))
    assert result.status == "failed" and result.raw == ["not json at all", fenced_mismatch, out_of_range]
    assert "outside the video" in result.error
    last = server.calls("gemini")[-1][3]["contents"]
    assert [c["role"] for c in last] == ["user", "model", "user", "model", "user"]
    assert "2 plans but 0 critical moments" in last[4]["parts"][0]["text"]
    assert len(server.uploads) == 1 and len(server.deleted) == 1  # one upload for all turns


def test_gemini_timeout_and_processing_failure(server, tmp_path):
    server.default = Reply(hang=True)
    started = time.perf_counter()
    result = _annotate(_gemini(server, timeout_s=0.5, max_retries=0), _job(tmp_path))
    assert result.status == "failed" and "timed out" in result.error and time.perf_counter() - started < 3
    assert len(server.deleted) == 1  # the upload is removed even when the call fails

    server.file_states = ["PROCESSING", "FAILED"]
    result = _annotate(_gemini(server), _job(tmp_path, seed=1))
    assert result.status == "failed" and "could not process the video" in result.error

    server.file_states = ["PROCESSING"]  # never becomes ACTIVE
    result = _annotate(_gemini(server, processing_timeout_s=0.2), _job(tmp_path, seed=2))
    assert result.status == "failed" and "still PROCESSING" in result.error


def test_gemini_key_from_environment(server, tmp_path, monkeypatch):
    monkeypatch.setenv("GEMINI_API_KEY", KEY)
    result = _annotate(make_annotator("gemini", base_url=server.url, poll_s=0.01), _job(tmp_path))
    assert result.status == "ok" and server.calls("gemini")[0][2]["x-goog-api-key"] == KEY


# --------------------------------------------------------------------------- whole runs


@pytest.mark.parametrize("backend", ["openai", "gemini"])
def test_pipeline_run_logs_costs_and_caps_concurrency(server, tmp_path, dataset, backend):
    server.default = Reply(delay_s=0.2)
    server.script = [Reply(f"Bearer {KEY} is what you sent")]  # a hostile echo: must be scrubbed
    out = tmp_path / "ann"
    annotator = (_openai if backend == "openai" else _gemini)(server)
    summary = annotate_dataset(dataset, out, annotator, RunOptions(concurrency=2))
    assert (summary.annotated, summary.failed) == (4, 0)
    assert server.peak_in_flight == 2
    calls = [json.loads(x) for x in (out / "calls.jsonl").read_text().splitlines()]
    replies = [c for c in calls if c["call"] == "generate"]
    assert len(replies) == 5 and sum(c["input_tokens"] for c in replies) == summary.input_tokens == 5 * 5000
    assert summary.cost_usd == pytest.approx(sum(c["cost_usd"] for c in replies), abs=1e-6) and summary.cost_usd > 0
    records = read_annotations(out)
    assert all(r["backend"] == backend and r["status"] == "ok" for r in records.values())
    assert all((out / r["clip_path"]).is_file() for r in records.values())
    report = quality_report(records, open_dataset(dataset), 5)
    assert report["plan_count_agreement"] == 1.0 and report["frame_err_mean"] > 0  # evenly spaced guesses
    for path in out.rglob("*"):
        if path.is_file() and path.suffix in (".jsonl", ".json"):
            assert KEY not in path.read_text()


def test_sigint_mid_run_then_resume(server, tmp_path, dataset):
    """A real Ctrl-C (SIGINT) to `seal annotate` mid-run; the re-run finishes with no episode lost
    or duplicated."""
    server.default = Reply(delay_s=0.6)
    out = tmp_path / "ann"
    env = {**os.environ, "OPENAI_API_KEY": KEY, "PYTHONPATH": str(Path(__file__).parents[1] / "src")}
    cmd = [sys.executable, "-c", "import sys; from seal.cli import main; sys.exit(main())", "annotate",
           str(dataset), "--backend", "openai", "--base-url", f"{server.url}/v1", "--out", str(out),
           "--concurrency", "1"]
    # SIG_DFL in the child: under a background job SIGINT arrives ignored, and Python then never
    # installs its KeyboardInterrupt handler (the Ctrl-C would be lost, not tested).
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        # Generous: a fresh venv's first import compiles every package, slow on a loaded machine.
        deadline = time.monotonic() + 180
        path = out / "annotations.jsonl"
        while not (path.exists() and path.read_text().count("\n") >= 1):
            assert time.monotonic() < deadline and proc.poll() is None, "no episode annotated in time"
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130 and "interrupted" in err
    first = read_annotations(out)
    assert 1 <= len(first) < 4

    server.default = Reply()
    summary = annotate_dataset(dataset, out, _openai(server), RunOptions(concurrency=1))
    assert summary.skipped == len(first) and summary.annotated == 4 - len(first)
    lines = [json.loads(x) for x in (out / "annotations.jsonl").read_text().splitlines()]
    assert sorted(r["episode_index"] for r in lines) == [0, 1, 2, 3]
