"""Annotators: something that turns one episode's clip into checked plans and critical moments.

``VLMAnnotator`` asks a model and owns everything around the wire call, for both backends:

- ``gemini``: ``google-genai``; the 10 fps mp4 goes up through the Files API (upload, wait
  until the file is ACTIVE, refer to it by URI with ``VideoMetadata(fps=10)`` so the model
  samples every frame, delete it afterwards). Gemini 2.5 Pro by default.
- ``openai``: any OpenAI-compatible chat-completions server through the ``openai`` SDK; the
  clip's frames go as images, each after a caption with its frame number and time.

Both SDKs are built exactly as the VLM verifier builds them (:mod:`seal.verify.vlm`: their own
retries off, keys read by the SDK from its usual environment variables unless given, keys
scrubbed from every text we keep). On top of the wire call:

- transient failures (408/429/5xx, timeouts, dropped connections) are retried with exponential
  backoff, each attempt bounded by ``timeout_s``; when the budget is spent the episode fails
  with the reason kept;
- a reply that breaks the output contract is sent back in the same conversation with the exact
  problem (:func:`seal.annotate.prompt.retry_message`), at most ``max_invalid`` times; then the
  episode fails with every raw reply kept;
- errors retrying cannot fix (400/401/403/404: wrong key, model or URL) raise
  :class:`AnnotatorCallError` and stop the run;
- every call is logged (tokens, cost, latency, outcome) and valid answers are cached on disk,
  keyed by backend, model, settings, prompt and the clip's pixels.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import logging
import time
import weakref
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from seal.annotate.base import BACKENDS, DEFAULT_MODELS, Annotator, AnnotatorResult, EpisodeInput  # noqa: F401
from seal.annotate.parse import AnswerError, parse_answer
from seal.annotate.prompt import PROMPT_VERSION, build_prompt, frame_label, retry_message
from seal.errors import InvalidInput, SealError

# Shared with the VLM verifier so both speak to the SDKs, price calls and guard keys the same way.
from seal.vlm import (
    gemini_is_transient,
    openai_is_transient,
    PRICES_PER_MTOK,
    ResponseCache,
    require_key,
    require_sdk,
    Secrets,
    cost_usd,
    encode_image,
)

log = logging.getLogger(__name__)

class AnnotatorCallError(SealError, RuntimeError):
    """The model server refused the request in a way retrying cannot fix (key, model, URL)."""


class _Unavailable(Exception):
    """Transient errors used up the retry budget."""

    def __init__(self, error: str, attempts: int):
        super().__init__(error)
        self.error, self.attempts = error, attempts


# --------------------------------------------------------------------------- config


@dataclass
class AnnotatorConfig:
    backend: str
    model: str
    base_url: str | None = None
    timeout_s: float = 180.0  # one HTTP attempt; a long video answer from a thinking model is slow
    max_retries: int = 3  # extra attempts per call on transient errors
    backoff_s: float = 2.0
    max_backoff_s: float = 60.0
    max_invalid: int = 2  # extra turns after a reply that breaks the contract
    processing_timeout_s: float = 300.0  # Gemini: wait for an uploaded video to become ACTIVE
    poll_s: float = 2.0
    temperature: float | None = 0.0
    max_output_tokens: int | None = None
    image_format: str = "jpeg"  # openai: frames as JPEG keep a 100-frame request small
    frame_stride: int = 1  # openai: send every n-th clip frame (captions keep true numbers)
    cache_dir: str | Path | None = None

    def validate(self) -> None:
        if self.backend not in ("gemini", "openai"):
            raise InvalidInput(f"unknown annotation backend {self.backend!r}; valid: {', '.join(BACKENDS)}")
        for name in ("timeout_s", "processing_timeout_s", "poll_s"):
            if getattr(self, name) <= 0:
                raise InvalidInput(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("max_retries", "max_invalid", "backoff_s", "max_backoff_s"):
            if getattr(self, name) < 0:
                raise InvalidInput(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.image_format not in ("png", "jpeg"):
            raise InvalidInput(f"image_format must be 'png' or 'jpeg', got {self.image_format!r}")
        if self.frame_stride < 1:
            raise InvalidInput(f"frame_stride must be >= 1, got {self.frame_stride}")

    def backoff(self, retry: int) -> float:
        return min(self.backoff_s * (2**retry), self.max_backoff_s)

    def settings(self) -> dict:
        """What changes an answer (cache key); nothing secret."""
        return {"temperature": self.temperature, "max_output_tokens": self.max_output_tokens,
                "image_format": self.image_format, "frame_stride": self.frame_stride,
                "prompt_version": PROMPT_VERSION}


# --------------------------------------------------------------------------- wire backends


@dataclass
class _Reply:
    text: str
    input_tokens: int
    output_tokens: int
    extra: dict = field(default_factory=dict)


class _Chat(Protocol):
    """One backend's wire calls. ``turns`` alternates model replies and our follow-ups."""

    async def prepare(self, job: EpisodeInput, call: Callable) -> Any: ...

    async def complete(self, prepared: Any, prompt: str, turns: list[str]) -> _Reply: ...

    async def release(self, prepared: Any) -> None: ...

    def is_transient(self, exc: BaseException) -> bool: ...

    async def aclose(self) -> None: ...


class _OpenAIChat:
    def __init__(self, cfg: AnnotatorConfig, api_key: str | None):
        from openai import AsyncOpenAI

        kwargs: dict[str, Any] = {"max_retries": 0, "timeout": cfg.timeout_s}
        if api_key is not None:
            kwargs["api_key"] = api_key
        if cfg.base_url is not None:
            kwargs["base_url"] = cfg.base_url
        self._client = AsyncOpenAI(**kwargs)  # else OPENAI_API_KEY / OPENAI_BASE_URL, as the SDK reads them
        self._cfg = cfg

    async def prepare(self, job: EpisodeInput, call: Callable) -> list[dict]:
        if job.clip is None:
            raise InvalidInput(f"episode {job.episode}: the openai annotator needs the clip's frames")
        fmt, fps = self._cfg.image_format, job.frame_map.video_fps
        mime = f"image/{fmt}"
        content: list[dict] = []
        for v in range(0, len(job.clip), self._cfg.frame_stride):
            data = base64.b64encode(encode_image(job.clip[v], fmt, f"clip[{v}]")).decode("ascii")
            content += [{"type": "text", "text": frame_label(v, fps)},
                        {"type": "image_url", "image_url": {"url": f"data:{mime};base64,{data}"}}]
        return content

    async def complete(self, frames: list[dict], prompt: str, turns: list[str]) -> _Reply:
        messages: list[dict] = [{"role": "user", "content": [{"type": "text", "text": prompt}, *frames]}]
        for k, text in enumerate(turns):
            messages.append({"role": "assistant" if k % 2 == 0 else "user", "content": text})
        params: dict[str, Any] = {}
        if self._cfg.temperature is not None:
            params["temperature"] = self._cfg.temperature
        if self._cfg.max_output_tokens is not None:
            params["max_completion_tokens"] = self._cfg.max_output_tokens
        resp = await self._client.chat.completions.create(model=self._cfg.model, messages=messages, **params)
        choice = resp.choices[0] if resp.choices else None
        usage = resp.usage
        return _Reply(text=(choice.message.content if choice else None) or "",
                      input_tokens=int(getattr(usage, "prompt_tokens", 0) or 0),
                      output_tokens=int(getattr(usage, "completion_tokens", 0) or 0),
                      extra={"finish_reason": getattr(choice, "finish_reason", None)})

    async def release(self, prepared: Any) -> None:
        return None

    def is_transient(self, exc: BaseException) -> bool:
        return openai_is_transient(exc)

    async def aclose(self) -> None:
        await self._client.close()


class _GeminiChat:
    def __init__(self, cfg: AnnotatorConfig, api_key: str | None):
        from google import genai
        from google.genai import types

        http = types.HttpOptions(timeout=int(cfg.timeout_s * 1000),  # milliseconds in this SDK
                                 retry_options=types.HttpRetryOptions(attempts=1))
        if cfg.base_url is not None:
            http.base_url = cfg.base_url
        self._client = genai.Client(api_key=api_key, http_options=http)  # None: GOOGLE_/GEMINI_API_KEY
        self._types = types
        self._cfg = cfg

    async def prepare(self, job: EpisodeInput, call: Callable) -> Any:
        """Upload the mp4 and wait until Gemini has processed it. Returns (File, clip fps)."""
        t = self._types
        if job.clip_path is None or not Path(job.clip_path).is_file():
            raise InvalidInput(f"episode {job.episode}: the gemini annotator needs the clip as an mp4 file")
        config = t.UploadFileConfig(mime_type="video/mp4", display_name=f"seal-episode-{job.episode:06d}")
        uploaded = await call(lambda: self._client.aio.files.upload(file=str(job.clip_path), config=config))
        deadline = time.monotonic() + self._cfg.processing_timeout_s
        current = uploaded
        try:
            while _state(current) != "ACTIVE":
                if _state(current) == "FAILED":
                    why = getattr(getattr(current, "error", None), "message", None) or "no reason given"
                    raise _Unavailable(f"Gemini could not process the video {current.name}: {why}", 1)
                if time.monotonic() > deadline:
                    raise _Unavailable(f"video {current.name} still {_state(current)} after "
                                       f"{self._cfg.processing_timeout_s:g} s", 1)
                await asyncio.sleep(self._cfg.poll_s)
                current = await call(lambda: self._client.aio.files.get(name=uploaded.name))
        except BaseException:
            await self.release((uploaded, 0))
            raise
        return current, job.frame_map.video_fps

    async def complete(self, prepared: tuple[Any, int], prompt: str, turns: list[str]) -> _Reply:
        t = self._types
        file, fps = prepared
        # Telling Gemini the clip's rate makes it sample every frame (its default is 1 fps).
        video = t.Part(file_data=t.FileData(file_uri=file.uri, mime_type="video/mp4"),
                       video_metadata=t.VideoMetadata(fps=float(fps)))
        contents = [t.Content(role="user", parts=[video, t.Part.from_text(text=prompt)])]
        for k, text in enumerate(turns):
            contents.append(t.Content(role="model" if k % 2 == 0 else "user", parts=[t.Part.from_text(text=text)]))
        config = t.GenerateContentConfig(temperature=self._cfg.temperature,
                                         max_output_tokens=self._cfg.max_output_tokens,
                                         response_mime_type="application/json")
        resp = await self._client.aio.models.generate_content(model=self._cfg.model, contents=contents, config=config)
        usage = resp.usage_metadata
        output = (getattr(usage, "candidates_token_count", 0) or 0) + (getattr(usage, "thoughts_token_count", 0) or 0)
        finish = resp.candidates[0].finish_reason if resp.candidates else None
        return _Reply(text=resp.text or "", input_tokens=int(getattr(usage, "prompt_token_count", 0) or 0),
                      output_tokens=int(output), extra={"finish_reason": str(finish) if finish is not None else None})

    async def release(self, prepared: tuple[Any, int]) -> None:
        # Best effort: uploaded files expire by themselves after 48 h anyway.
        file = prepared[0]
        try:
            await asyncio.wait_for(self._client.aio.files.delete(name=file.name), self._cfg.timeout_s)
        except Exception as exc:  # noqa: BLE001 - cleanup must not hide the real outcome
            log.info("could not delete uploaded file %s: %s", getattr(file, "name", "?"), type(exc).__name__)

    def is_transient(self, exc: BaseException) -> bool:
        return gemini_is_transient(exc)

    async def aclose(self) -> None:
        await self._client.aio.aclose()


def _state(file: Any) -> str:
    state = getattr(file, "state", None)
    if state is None:
        return "ACTIVE"  # servers that do not report processing states serve files at once
    return str(getattr(state, "value", state)).upper()


_CHATS = {"openai": _OpenAIChat, "gemini": _GeminiChat}


# --------------------------------------------------------------------------- the annotator


def cache_key(cfg: AnnotatorConfig, prompt: str, clip: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(json.dumps({"v": 1, "backend": cfg.backend, "model": cfg.model, "settings": cfg.settings(),
                         "prompt": prompt}, sort_keys=True).encode())
    arr = np.ascontiguousarray(clip)
    h.update(f"|{arr.shape}|{arr.dtype}|".encode())
    h.update(arr.tobytes())
    return h.hexdigest()


class VLMAnnotator:
    needs_clip = True

    def __init__(self, config: AnnotatorConfig, api_key: str | None = None, prices: dict | None = None):
        config.validate()
        require_sdk(config.backend)
        require_key(config.backend, api_key)
        self.config = config
        self.backend, self.model = config.backend, config.model
        self.prices = {**PRICES_PER_MTOK, **(prices or {})}
        self._secrets = Secrets(config.backend, api_key)
        self._new_chat = lambda: _CHATS[config.backend](config, api_key)  # the key stays in this closure
        self._chats: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self._cache = ResponseCache(config.cache_dir) if config.cache_dir is not None else None

    def __repr__(self) -> str:
        return f"VLMAnnotator({self.config!r})"

    def _chat(self) -> _Chat:
        # An SDK client's connection pool belongs to the event loop it was first used on.
        loop = asyncio.get_running_loop()
        if loop not in self._chats:
            self._chats[loop] = self._new_chat()
        return self._chats[loop]

    async def annotate(self, job: EpisodeInput) -> AnnotatorResult:
        if job.clip is None:
            raise InvalidInput(f"episode {job.episode}: the {self.backend} annotator needs the clip")
        n = job.frame_map.num_video_frames
        prompt = build_prompt(job.instruction, n, job.frame_map.video_fps)
        key = cache_key(self.config, prompt, job.clip)
        if self._cache is not None and (hit := self._cache.get(key)) is not None:
            try:
                return AnnotatorResult(status="ok", annotation=parse_answer(hit["raw"], job.frame_map),
                                       raw=[hit["raw"]], cached=True)
            except (AnswerError, KeyError):
                pass  # a stale or foreign entry: ask again
        chat = self._chat()
        result = AnnotatorResult(status="failed")

        async def call(fn: Callable[[], Awaitable[Any]], what: str = "upload") -> Any:
            return await self._with_retries(chat, fn, result, job.episode, what)

        try:
            prepared = await chat.prepare(job, call)
        except _Unavailable as exc:
            result.error = f"preparing the request failed after {exc.attempts} attempt(s): {exc.error}"
            return result
        try:
            turns: list[str] = []
            for turn in range(self.config.max_invalid + 1):
                history = list(turns)
                reply: _Reply = await call(lambda h=history: chat.complete(prepared, prompt, h), "generate")
                text = self._secrets.scrub(reply.text)
                result.raw.append(text)
                try:
                    result.annotation = parse_answer(text, job.frame_map)
                except AnswerError as exc:
                    result.calls[-1]["outcome"] = f"invalid: {exc}"
                    result.error = f"reply {turn + 1} invalid: {exc}"
                    turns += [reply.text, retry_message(str(exc), n)]
                    continue
                result.status, result.error = "ok", ""
                if self._cache is not None:
                    self._cache.put(key, {"raw": text, "backend": self.backend, "model": self.model,
                                          "input_tokens": result.input_tokens, "output_tokens": result.output_tokens,
                                          "cost_usd": result.cost_usd})
                return result
            result.error = (f"no valid answer after {self.config.max_invalid + 1} replies; last problem: "
                            f"{result.error.split(': ', 1)[-1]}")
            return result
        except _Unavailable as exc:
            result.error = f"model unavailable after {exc.attempts} attempt(s): {exc.error}"
            return result
        finally:
            await chat.release(prepared)

    async def _with_retries(self, chat: _Chat, fn: Callable[[], Awaitable[Any]], result: AnnotatorResult,
                            episode: int, what: str) -> Any:
        error = ""
        for retry in range(self.config.max_retries + 1):
            started = time.perf_counter()
            row: dict[str, Any] = {"episode": episode, "call": what, "attempt": retry + 1,
                                   "backend": self.backend, "model": self.model}
            try:
                # wait_for is the hard bound; the SDK's own timeout may not cover every phase
                value = await asyncio.wait_for(fn(), self.config.timeout_s)
            except TimeoutError:
                error = f"timed out after {self.config.timeout_s:g} s"
            except Exception as exc:  # noqa: BLE001 - classified just below
                if not chat.is_transient(exc):
                    raise AnnotatorCallError(f"{self.backend}:{self.model}: request rejected "
                                             f"({self._describe(exc)}); check the model name, base URL and API key"
                                             ) from None  # no chained SDK exception: it may carry headers
                error = self._describe(exc)
            else:
                row["latency_s"] = round(time.perf_counter() - started, 3)
                if isinstance(value, _Reply):
                    cost, note = cost_usd(self.model, value.input_tokens, value.output_tokens, self.prices)
                    row.update(input_tokens=value.input_tokens, output_tokens=value.output_tokens,
                               cost_usd=cost, outcome="reply", **value.extra)
                    if note:
                        row["cost_note"] = note
                else:
                    row["outcome"] = "ok"
                result.calls.append(row)
                return value
            row.update(latency_s=round(time.perf_counter() - started, 3), outcome=f"error: {error}")
            result.calls.append(row)
            if retry < self.config.max_retries:
                delay = self.config.backoff(retry)
                log.info("%s episode %d: %s attempt %d failed (%s); retrying in %.2f s",
                         self.backend, episode, what, retry + 1, error, delay)
                await asyncio.sleep(delay)
        raise _Unavailable(error, self.config.max_retries + 1)

    def _describe(self, exc: BaseException) -> str:
        status = getattr(exc, "status_code", None) or getattr(exc, "code", None)
        text = type(exc).__name__ + (f" HTTP {status}" if isinstance(status, int) else "")
        detail = str(exc).strip()
        if detail:
            text += f": {detail[:300]}"
        return self._secrets.scrub(text)

    async def aclose(self) -> None:
        chat = self._chats.pop(asyncio.get_running_loop(), None)
        if chat is not None:
            await chat.aclose()


def make_annotator(backend: str, model: str | None = None, base_url: str | None = None, **opts: Any) -> Annotator:
    """``offline`` or a VLM annotator. ``opts``: ``api_key``, ``prices`` and AnnotatorConfig fields."""
    if backend not in BACKENDS:
        raise InvalidInput(f"unknown annotation backend {backend!r}; valid: {', '.join(BACKENDS)}")
    if backend == "offline":
        from seal.annotate.offline import OfflineAnnotator

        if model not in (None, DEFAULT_MODELS["offline"]) or base_url is not None:
            raise InvalidInput("the offline annotator takes no --model or --base-url")
        return OfflineAnnotator()
    api_key = opts.pop("api_key", None)
    prices = opts.pop("prices", None)
    valid = set(AnnotatorConfig.__dataclass_fields__) - {"backend", "model", "base_url"}
    unknown = sorted(set(opts) - valid)
    if unknown:
        raise InvalidInput(f"unknown annotator option(s) {unknown}; valid: {sorted(valid | {'api_key', 'prices'})}")
    config = AnnotatorConfig(backend=backend, model=model or DEFAULT_MODELS[backend], base_url=base_url, **opts)
    return VLMAnnotator(config, api_key=api_key, prices=prices)
