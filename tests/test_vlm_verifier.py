"""The VLM verifier against a real local HTTP server that speaks both wire formats.

The server (stdlib ``http.server`` in a thread on 127.0.0.1) implements
``POST /v1/chat/completions`` (OpenAI) and ``POST /{v1,v1beta}/models/{model}:generateContent``
(Gemini REST, whichever version the installed google-genai calls). Each test scripts its
replies; the server records every request and the peak number of requests in flight.
"""

from __future__ import annotations

import asyncio
import base64
import io
import json
import logging
import re
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler

import numpy as np
import pytest
from PIL import Image

from _local_http import scrub_env, send_json, serving

from seal.errors import InvalidInput
from seal.verify.base import VerifyRequest
from seal.verify.vlm import (
    PRICES_PER_MTOK,
    VerifierCallError,
    VLMVerifier,
    build_prompt,
    make_vlm_verifier,
    parse_answer,
    price_for,
)

KEY = "sk-test-9f3b1c7e-DO-NOT-LEAK"
GOOD = "Image 1: the soup can is at the left of the basket.\nThe gripper holds it firmly.\nVerification: Success"
BAD = "I located the soup can near the front.\nThe gripper is empty.\n**Verification: Failure**"
GEMINI_PATH = re.compile(r"^/v1(?:beta)?/models/([^/:]+):generateContent$")


# --------------------------------------------------------------------------- fake server


@dataclass
class Reply:
    """One scripted reply. ``text`` becomes a model answer; ``status`` != 200 an error."""

    text: str = GOOD
    status: int = 200
    hang: bool = False  # never answer (until the test ends)
    delay_s: float = 0.0
    usage: tuple[int, int] = (1200, 80)


@dataclass
class FakeServer:
    url: str
    requests: list = field(default_factory=list)  # (path, headers, json body)
    script: list = field(default_factory=list)  # Replies consumed in order, then `default`
    default: Reply = field(default_factory=Reply)
    in_flight: int = 0
    peak_in_flight: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    release: threading.Event = field(default_factory=threading.Event)

    def next_reply(self) -> Reply:
        with self.lock:
            return self.script.pop(0) if self.script else self.default

    @property
    def calls(self) -> int:
        return len(self.requests)


def _openai_body(reply: Reply, model: str) -> dict:
    return {
        "id": "chatcmpl-test",
        "object": "chat.completion",
        "created": 0,
        "model": model,
        "choices": [
            {"index": 0, "message": {"role": "assistant", "content": reply.text}, "finish_reason": "stop"}
        ],
        "usage": {
            "prompt_tokens": reply.usage[0],
            "completion_tokens": reply.usage[1],
            "total_tokens": sum(reply.usage),
        },
    }


def _gemini_body(reply: Reply) -> dict:
    return {
        "candidates": [
            {"content": {"role": "model", "parts": [{"text": reply.text}]}, "finishReason": "STOP", "index": 0}
        ],
        # 30 "thinking" tokens on top of the visible answer: billed as output.
        "usageMetadata": {
            "promptTokenCount": reply.usage[0],
            "candidatesTokenCount": reply.usage[1],
            "thoughtsTokenCount": 30,
            "totalTokenCount": sum(reply.usage) + 30,
        },
        "modelVersion": "gemini-2.5-pro",
    }


def _error_body(status: int, gemini: bool) -> dict:
    if gemini:
        return {"error": {"code": status, "message": f"scripted {status}", "status": "UNAVAILABLE"}}
    return {"error": {"message": f"scripted {status}", "type": "server_error", "code": status}}


def _make_handler(server: FakeServer):
    class Handler(BaseHTTPRequestHandler):
        def do_POST(self):  # noqa: N802 (http.server naming)
            length = int(self.headers.get("content-length", 0))
            body = json.loads(self.rfile.read(length) or b"{}")
            gemini = GEMINI_PATH.match(self.path)
            if self.path != "/v1/chat/completions" and not gemini:
                return self._send(404, {"error": {"message": f"no route {self.path}"}})
            with server.lock:
                server.requests.append((self.path, {k.lower(): v for k, v in self.headers.items()}, body))
                server.in_flight += 1
                server.peak_in_flight = max(server.peak_in_flight, server.in_flight)
            try:
                reply = server.next_reply()
                if reply.hang:
                    server.release.wait(timeout=20)  # bounded: the fixture releases it at teardown
                    return
                time.sleep(reply.delay_s)
                if reply.status != 200:
                    return self._send(reply.status, _error_body(reply.status, bool(gemini)))
                out = _gemini_body(reply) if gemini else _openai_body(reply, body.get("model", ""))
                self._send(200, out)
            finally:
                with server.lock:
                    server.in_flight -= 1

        def _send(self, status: int, payload: dict):
            send_json(self, status, payload)  # the client may have given up (timeout tests)

        def log_message(self, *args):  # keep test output quiet
            pass

    return Handler


@pytest.fixture
def server():
    fake = FakeServer(url="")
    with serving(fake, _make_handler(fake)):
        yield fake


@pytest.fixture(autouse=True)
def clean_env(monkeypatch):
    scrub_env(monkeypatch)


# --------------------------------------------------------------------------- helpers


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(224, 224, 3), dtype=np.uint8)


def _request(subplan="pick up the alphabet soup", candidate=0, seed=0) -> VerifyRequest:
    return VerifyRequest(
        subplan=subplan,
        instruction="put both the alphabet soup and the tomato sauce in the basket",
        plans=("pick up the alphabet soup", "place it in the basket"),
        first_agent=_image(seed),
        final_agent=_image(seed + 1),
        final_wrist=_image(seed + 2),
        task="libero_10/0",
        candidate=candidate,
    )


def _openai(server, **opts) -> VLMVerifier:
    opts.setdefault("api_key", KEY)
    opts.setdefault("backoff_s", 0.01)
    opts.setdefault("timeout_s", 5.0)
    return make_vlm_verifier("openai", base_url=f"{server.url}/v1", **opts)


def _gemini(server, **opts) -> VLMVerifier:
    opts.setdefault("api_key", KEY)
    opts.setdefault("backoff_s", 0.01)
    opts.setdefault("timeout_s", 5.0)
    return make_vlm_verifier("gemini", base_url=server.url, **opts)


def _run(coro):
    return asyncio.run(coro)


def _decode_png(data: bytes) -> np.ndarray:
    assert data.startswith(b"\x89PNG")
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def _decode_data_url(url: str) -> np.ndarray:
    assert url.startswith("data:image/png;base64,")
    return _decode_png(base64.b64decode(url.split(",", 1)[1]))


def _cost(model, tin, tout):
    pin, pout = PRICES_PER_MTOK[model]
    return (tin * pin + tout * pout) / 1e6


# --------------------------------------------------------------------------- parsing and prompt


@pytest.mark.parametrize(
    "text,expected",
    [
        ("reasoning\nVerification: Success", True),
        ("reasoning\nverification:failure", False),
        ("reasoning\n  **Verification: Success**  ", True),
        ("reasoning\n**Verification:** *Failure*.", False),
        ("reasoning\n### VERIFICATION : SUCCESS\n", True),
        ("Verification: Success\nmore thought\nVerification: Failure", False),  # last counts
        ("It looks like a Verification: Success to me", None),  # not a verdict line
        ("Verification: maybe", None),
        ("", None),
    ],
)
def test_parse_answer(text, expected):
    assert parse_answer(text).success is expected


def test_parse_answer_rationale_is_text_before_last_verdict():
    parsed = parse_answer("  Step 1: found it.\nStep 2: held.\n\nVerification: Success\n")
    assert parsed.rationale == "Step 1: found it.\nStep 2: held."
    assert parse_answer("nonsense").rationale == "unparseable answer"


def test_prompt_carries_subplan_and_output_contract():
    prompt = build_prompt(_request())
    assert '"pick up the alphabet soup"' in prompt
    assert "place it in the basket" in prompt  # the whole plan, to resolve "it"
    assert prompt.rstrip().endswith("Verification: Success\nVerification: Failure")
    for needle in ("Image 1", "Image 2", "Image 3", "bottom edge", "upright", "red area", "shut"):
        assert needle in prompt


def test_price_lookup():
    assert price_for("gpt-4o-2024-08-06", PRICES_PER_MTOK) == PRICES_PER_MTOK["gpt-4o"]
    assert price_for("gpt-4o-mini", PRICES_PER_MTOK) == PRICES_PER_MTOK["gpt-4o-mini"]
    assert price_for("models/gemini-2.5-pro", PRICES_PER_MTOK) == PRICES_PER_MTOK["gemini-2.5-pro"]
    assert price_for("my-local-llava", PRICES_PER_MTOK) is None


# --------------------------------------------------------------------------- construction errors


def test_unknown_backend_names_valid_ones():
    with pytest.raises(InvalidInput, match="openai, gemini"):
        make_vlm_verifier("claude")


def test_missing_key_names_env_var():
    with pytest.raises(InvalidInput, match="OPENAI_API_KEY"):
        make_vlm_verifier("openai")
    with pytest.raises(InvalidInput, match="GEMINI_API_KEY"):
        make_vlm_verifier("gemini")


def test_unknown_option_and_bad_values():
    with pytest.raises(InvalidInput, match="unknown VLM verifier option"):
        make_vlm_verifier("openai", api_key=KEY, timeout=3)
    with pytest.raises(InvalidInput, match="max_concurrency"):
        make_vlm_verifier("openai", api_key=KEY, max_concurrency=0)


def test_missing_image_is_invalid_input(server):
    req = _request()
    req.final_wrist = None
    with pytest.raises(InvalidInput, match="final_wrist"):
        _run(_openai(server).verify(req))
    assert server.calls == 0


def test_defaults():
    v = make_vlm_verifier("openai", api_key=KEY)
    assert v.config.model == "gpt-4o" and v.needs_images and v.atoms_needed(_request(), ["a"]) == []
    assert make_vlm_verifier("gemini", api_key=KEY).config.model == "gemini-2.5-pro"


# --------------------------------------------------------------------------- openai backend


def test_openai_success_and_failure_verdicts(server):
    v = _openai(server)
    server.script = [Reply(GOOD, usage=(1000, 50)), Reply(BAD, usage=(1100, 70))]
    ok = _run(v.verify(_request()))
    bad = _run(v.verify(_request(candidate=1)))

    assert ok.success is True and bad.success is False
    assert ok.rationale.startswith("Image 1: the soup can") and ok.rationale.endswith("holds it firmly.")
    assert ok.raw == GOOD
    assert (ok.input_tokens, ok.output_tokens) == (1000, 50)
    assert ok.cost_usd == pytest.approx(_cost("gpt-4o", 1000, 50))
    assert bad.cost_usd == pytest.approx(_cost("gpt-4o", 1100, 70))
    assert ok.extra["cached"] is False and "cost_note" not in ok.extra
    assert ok.latency_s > 0


def test_openai_request_carries_three_images_and_subplan(server):
    req = _request()
    _run(_openai(server).verify(req))
    path, headers, body = server.requests[0]
    assert path == "/v1/chat/completions"
    assert headers["authorization"] == f"Bearer {KEY}"
    assert body["model"] == "gpt-4o"
    [message] = body["messages"]  # one user message holds text and images
    assert message["role"] == "user"
    texts = [p["text"] for p in message["content"] if p["type"] == "text"]
    urls = [p["image_url"]["url"] for p in message["content"] if p["type"] == "image_url"]
    assert "pick up the alphabet soup" in texts[0]
    assert len(urls) == 3
    for url, original in zip(urls, (req.first_agent, req.final_agent, req.final_wrist)):
        np.testing.assert_array_equal(_decode_data_url(url), original)  # right order, lossless


def test_unknown_model_costs_zero_with_note(server):
    v = make_vlm_verifier("openai", model="local-llava", base_url=f"{server.url}/v1", api_key=KEY)
    verdict = _run(v.verify(_request()))
    assert verdict.success is True and verdict.cost_usd == 0.0
    assert "local-llava" in verdict.extra["cost_note"]
    assert server.requests[0][2]["model"] == "local-llava"


def test_malformed_answer_is_unknown_with_raw_kept(server):
    server.script = [Reply("The can seems to be held, probably fine.")]
    verdict = _run(_openai(server).verify(_request()))
    assert verdict.success is None
    assert verdict.rationale == "unparseable answer"
    assert verdict.raw == "The can seems to be held, probably fine."
    assert verdict.input_tokens == 1200  # the call was still paid for


def test_429_then_success_is_retried(server):
    server.script = [Reply(status=429), Reply(status=503), Reply(GOOD)]
    verdict = _run(_openai(server, max_retries=3).verify(_request()))
    assert verdict.success is True
    assert server.calls == 3 and verdict.extra["attempts"] == 3


def test_500s_beyond_retry_budget_give_unknown_verdict(server):
    server.default = Reply(status=500)
    verdict = _run(_openai(server, max_retries=2).verify(_request()))
    assert server.calls == 3  # first try + 2 retries, no hidden SDK retries on top
    assert verdict.success is None
    assert verdict.extra["attempts"] == 3
    assert "500" in verdict.extra["error"] and "verifier unavailable" in verdict.rationale


def test_backoff_is_exponential(server):
    server.default = Reply(status=500)
    started = time.perf_counter()
    _run(_openai(server, max_retries=3, backoff_s=0.1).verify(_request()))
    assert time.perf_counter() - started >= 0.1 + 0.2 + 0.4
    v = _openai(server, backoff_s=1.0, max_backoff_s=5.0)
    assert [v.config.backoff(i) for i in range(5)] == [1.0, 2.0, 4.0, 5.0, 5.0]


def test_permanent_error_raises_without_retry(server):
    server.default = Reply(status=401)
    with pytest.raises(VerifierCallError, match="401") as info:
        _run(_openai(server, max_retries=3).verify(_request()))
    assert server.calls == 1
    assert KEY not in str(info.value)


def test_hanging_server_times_out_within_bound(server):
    server.default = Reply(hang=True)
    v = _openai(server, timeout_s=0.5, max_retries=1, backoff_s=0.05)
    started = time.perf_counter()
    verdict = _run(v.verify(_request()))
    elapsed = time.perf_counter() - started
    assert verdict.success is None
    assert server.calls == 2  # the timeout is retried like any transient error
    assert 0.9 < elapsed < 2 * 0.5 + 0.05 + 1.0  # two attempts plus slack, no hang


def test_cache_hit_on_identical_request(server, tmp_path):
    v = _openai(server, cache_dir=tmp_path / "cache")
    first = _run(v.verify(_request()))
    second = _run(v.verify(_request()))
    assert server.calls == 1
    assert second.success is first.success is True
    assert second.extra["cached"] is True and first.extra["cached"] is False
    assert second.cost_usd == 0.0 and second.input_tokens == 0  # (no latency bound: this machine is shared)
    assert second.extra["original_cost_usd"] == pytest.approx(first.cost_usd)
    assert second.rationale == first.rationale and second.raw == first.raw

    # A fresh verifier on the same directory (a later run) hits too.
    third = _run(_openai(server, cache_dir=tmp_path / "cache").verify(_request()))
    assert third.extra["cached"] is True and server.calls == 1

    # Different pixels, sub-plan or model are different questions.
    _run(v.verify(_request(seed=10)))
    _run(v.verify(_request(subplan="place it in the basket")))
    _run(_openai(server, cache_dir=tmp_path / "cache", model="gpt-4o-mini").verify(_request()))
    assert server.calls == 4


def test_unparseable_and_failed_answers_are_not_cached(server, tmp_path):
    v = _openai(server, cache_dir=tmp_path / "cache", max_retries=0)
    server.script = [Reply("no verdict here"), Reply(status=500)]
    assert _run(v.verify(_request())).success is None
    assert _run(v.verify(_request())).success is None
    assert _run(v.verify(_request())).success is True
    assert _run(v.verify(_request())).extra["cached"] is True
    assert server.calls == 3


def test_api_key_never_leaks(server, tmp_path, caplog):
    caplog.set_level(logging.DEBUG)  # every logger, SDKs and HTTP stacks included
    cache = tmp_path / "cache"
    # A hostile or buggy server that echoes the key back in its answer.
    server.script = [Reply(status=429), Reply(f"The header said Bearer {KEY}.\nVerification: Success")]
    v = _openai(server, cache_dir=cache)
    verdict = _run(v.verify(_request()))
    cached = _run(v.verify(_request()))
    assert verdict.success is True and cached.extra["cached"] is True
    assert server.requests[-1][1]["authorization"] == f"Bearer {KEY}"  # it was really sent

    server.default = Reply(status=500)
    unavailable = _run(_openai(server, max_retries=1).verify(_request(seed=5)))
    with pytest.raises(VerifierCallError) as info:
        server.default = Reply(status=403)
        _run(_openai(server).verify(_request(seed=6)))

    texts = [repr(verdict), repr(cached), repr(unavailable), str(info.value), repr(v), caplog.text]
    texts += [p.read_text() for p in cache.rglob("*") if p.is_file()]
    assert list(cache.rglob("*.json"))
    assert "retrying in" in caplog.text and "HTTP Request" in caplog.text  # logs were captured
    for text in texts:
        assert KEY not in text
    assert "***" in verdict.raw


def test_concurrency_cap_is_respected(server):
    server.default = Reply(GOOD, delay_s=0.25)
    v = _openai(server, max_concurrency=2)

    async def many():
        return await asyncio.gather(*(v.verify(_request(candidate=i, seed=i)) for i in range(6)))

    verdicts = _run(many())
    assert all(x.success for x in verdicts)
    assert server.calls == 6
    assert server.peak_in_flight == 2  # capped, and the cap is actually used


def test_env_vars_configure_openai_with_no_explicit_args(server, monkeypatch):
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    monkeypatch.setenv("OPENAI_BASE_URL", f"{server.url}/v1")
    v = make_vlm_verifier("openai")
    verdict = _run(v.verify(_request()))
    assert verdict.success is True
    path, headers, _ = server.requests[0]
    assert path == "/v1/chat/completions" and headers["authorization"] == f"Bearer {KEY}"
    assert KEY not in repr(verdict)


def test_verifier_works_across_event_loops(server):
    v = _openai(server)
    assert _run(v.verify(_request())).success is True
    assert _run(v.verify(_request(candidate=1))).success is True  # a second asyncio.run


# --------------------------------------------------------------------------- gemini backend


def test_gemini_success_and_failure_verdicts(server):
    server.script = [Reply(GOOD, usage=(900, 40)), Reply(BAD, usage=(950, 60))]
    v = _gemini(server)
    ok = _run(v.verify(_request()))
    bad = _run(v.verify(_request(candidate=1)))
    assert ok.success is True and bad.success is False
    assert (ok.input_tokens, ok.output_tokens) == (900, 40 + 30)  # thinking counts as output
    assert ok.cost_usd == pytest.approx(_cost("gemini-2.5-pro", 900, 70))
    assert bad.rationale.endswith("The gripper is empty.")


def test_gemini_request_carries_three_images_and_subplan(server):
    req = _request()
    _run(_gemini(server).verify(req))
    path, headers, body = server.requests[0]
    assert GEMINI_PATH.match(path).group(1) == "gemini-2.5-pro"
    assert headers["x-goog-api-key"] == KEY
    [content] = body["contents"]
    parts = content["parts"]
    images = [p.get("inlineData") or p.get("inline_data") for p in parts]
    images = [i for i in images if i]
    texts = [p["text"] for p in parts if "text" in p]
    assert "pick up the alphabet soup" in texts[0]
    assert len(images) == 3
    for img, original in zip(images, (req.first_agent, req.final_agent, req.final_wrist)):
        assert (img.get("mimeType") or img.get("mime_type")) == "image/png"
        # google-genai sends inline bytes as URL-safe base64
        np.testing.assert_array_equal(_decode_png(base64.urlsafe_b64decode(img["data"])), original)


def test_gemini_retries_429_and_reads_env_key(server, monkeypatch):
    monkeypatch.setenv("GEMINI_API_KEY", KEY)
    server.script = [Reply(status=429), Reply(BAD)]
    v = make_vlm_verifier("gemini", base_url=server.url, backoff_s=0.01)
    verdict = _run(v.verify(_request()))
    assert verdict.success is False and server.calls == 2
    assert server.requests[-1][1]["x-goog-api-key"] == KEY


def test_gemini_exhausted_retries_and_timeout(server):
    server.default = Reply(status=503)
    verdict = _run(_gemini(server, max_retries=1).verify(_request()))
    assert verdict.success is None and server.calls == 2 and "503" in verdict.extra["error"]

    server.default = Reply(hang=True)
    started = time.perf_counter()
    verdict = _run(_gemini(server, timeout_s=0.5, max_retries=0).verify(_request(seed=3)))
    assert verdict.success is None and time.perf_counter() - started < 2.0
