"""A vision-language model as the verifier: three images and a question, one verdict back.

Two backends share everything except the wire call:

- ``openai``: any OpenAI-compatible chat-completions server through the official ``openai``
  SDK (``AsyncOpenAI``). ``OPENAI_API_KEY`` / ``OPENAI_BASE_URL`` are read by the SDK itself
  when no explicit key / base URL is given.
- ``gemini``: Google's ``google-genai`` SDK (``client.aio.models.generate_content``). The SDK
  reads ``GOOGLE_API_KEY`` / ``GEMINI_API_KEY`` itself; a base URL goes in ``HttpOptions``.

Reliability is ours, not the SDKs': their own retries are switched off (``max_retries=0``,
``HttpRetryOptions(attempts=1)``) so that exactly one policy applies to both backends and the
tests can see it: a per-call timeout, retries with exponential backoff on 408/429/5xx,
timeouts and connection errors, a concurrency cap and an on-disk cache of verdicts.

When the retry budget is spent on transient errors the verdict is *unknown*
(``success=None``, ``extra["error"]`` says why): one flaky call should not end an episode,
and the steering loop keeps unknown apart from failure and counts these errors per trial.
Errors that retrying cannot fix raise :class:`VerifierCallError` (a
:class:`~seal.errors.VerifierUnavailable`), which stops the run: any 4xx but 408 and 429 (401,
403, 404, 400: a wrong key, model or URL), and a server that was never reached at all (every
attempt of the first call failed to connect: nothing listens at the base URL).

API keys are never stored on the verifier, logged, cached, or put into a verdict or an error
message: every text that leaves this module goes through :func:`Secrets.scrub`.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import logging
import re
import time
import weakref
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from seal.errors import InvalidInput, VerifierUnavailable
from seal.verify.base import Verdict, VerifyRequest
from seal.vlm import (  # noqa: F401  (PRICES_PER_MTOK, price_for, cost_usd: part of this module's API)
    BACKENDS,
    DEFAULT_MODELS,
    PRICES_PER_MTOK,
    ResponseCache,
    Secrets,
    cost_usd,
    encode_image,
    gemini_is_transient,
    gemini_reached_server,
    openai_is_transient,
    openai_reached_server,
    price_for,
    require_key,
    require_sdk,
)

log = logging.getLogger(__name__)

CACHE_FORMAT = 1  # bump when the cached record or the key recipe changes


class VerifierCallError(VerifierUnavailable):
    """The model server refused the request in a way retrying cannot fix (key, model, URL), or
    could never be reached."""


# --------------------------------------------------------------------------- prompt

_PROMPT_TEMPLATE = """\
You are checking whether a robot arm has finished one step of a tabletop task. A simulator \
predicted how the scene will look once the robot carries out that step; decide from the \
pictures whether the step really succeeded.

Task: {instruction}
{plan_block}Step to check: "{subplan}"

Three camera images follow, in this order:
- Image 1: the front camera at the moment this step began.
- Image 2: the front camera at the predicted end of this step.
- Image 3: the camera on the robot's wrist at the predicted end of this step. The gripper \
fingers sit at the bottom edge of this picture.

Reason in this order:
1. Find the object that the step is about in Image 1 and say where it is. It is always \
somewhere in that picture, even when another object hides part of it. Look closely at its \
shape - a round can and a rectangular box are different objects. If nothing fits the name \
exactly, go with the object that fits it best.
2. Check the end state in Images 2 and 3, according to what the step asks for:
   - Picking something up: the gripper must be holding that same object, firmly enough that \
it will not slip out. For a pot or a bowl, having any part of it (rim, edge, handle) between \
the fingers counts as holding it.
   - Putting or placing something: the object must be in or on the target. If you cannot see \
the object at the end, compare Image 1 with Image 2 to tell whether it has left the table. A \
mug counts only if it stands upright. A pot counts only if it touches the red area of the \
burner.
   - Closing something: it must be shut completely, with no gap left.
   - Any other step: the pictures must show that the step has been done.
3. Think it through step by step before you decide.

The very last line of your answer must be exactly one of these two lines, with nothing after it:
Verification: Success
Verification: Failure"""

IMAGE_LABELS = (
    "Image 1 (front camera, step start):",
    "Image 2 (front camera, predicted end):",
    "Image 3 (wrist camera, predicted end):",
)


def build_prompt(request: VerifyRequest) -> str:
    """The question text (the image labels are added next to the images themselves)."""
    plan_block = ""
    if request.plans:
        steps = "\n".join(f"  {i}. {p}" for i, p in enumerate(request.plans, 1))
        plan_block = f"Whole plan:\n{steps}\n"
    return _PROMPT_TEMPLATE.format(
        instruction=request.instruction.strip() or "(not given)",
        plan_block=plan_block,
        subplan=request.subplan.strip(),
    )


# --------------------------------------------------------------------------- answer parsing

# One verdict line: markdown decoration (bold, italics, code, heading, quote, bullet) is
# allowed around the words, and so is trailing punctuation.
_DECOR = r"[\s*_`#>\-]*"
_VERDICT_LINE = re.compile(
    rf"^{_DECOR}verification{_DECOR}:{_DECOR}(success|failure){_DECOR}[.!]?{_DECOR}$",
    re.IGNORECASE | re.MULTILINE,
)


@dataclass
class ParsedAnswer:
    success: bool | None
    rationale: str


def parse_answer(text: str) -> ParsedAnswer:
    """The last ``Verification: Success|Failure`` line decides; the text before it is the why."""
    matches = list(_VERDICT_LINE.finditer(text or ""))
    if not matches:
        return ParsedAnswer(success=None, rationale="unparseable answer")
    last = matches[-1]
    return ParsedAnswer(
        success=last.group(1).lower() == "success",
        rationale=text[: last.start()].strip(),
    )


# --------------------------------------------------------------------------- backends


@dataclass
class _Answer:
    text: str
    input_tokens: int
    output_tokens: int
    extra: dict = field(default_factory=dict)


class _Backend(Protocol):
    async def complete(self, prompt: str, images: list[bytes], mime: str) -> _Answer: ...

    def is_transient(self, exc: BaseException) -> bool: ...

    def reached_server(self, exc: BaseException) -> bool: ...

    async def aclose(self) -> None: ...


class _OpenAIBackend:
    def __init__(self, model: str, base_url: str | None, api_key: str | None, cfg: "VLMConfig"):
        from openai import AsyncOpenAI

        kwargs: dict[str, Any] = {"max_retries": 0, "timeout": cfg.timeout_s}
        # Only pass what was given explicitly: otherwise the SDK reads OPENAI_API_KEY /
        # OPENAI_BASE_URL itself, exactly as it documents.
        if api_key is not None:
            kwargs["api_key"] = api_key
        if base_url is not None:
            kwargs["base_url"] = base_url
        self._client = AsyncOpenAI(**kwargs)
        self._model = model
        self._cfg = cfg

    async def complete(self, prompt: str, images: list[bytes], mime: str) -> _Answer:
        content: list[dict] = [{"type": "text", "text": prompt}]
        for label, data in zip(IMAGE_LABELS, images):
            url = f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"
            content += [{"type": "text", "text": label}, {"type": "image_url", "image_url": {"url": url}}]
        params: dict[str, Any] = {}
        if self._cfg.temperature is not None:
            params["temperature"] = self._cfg.temperature
        if self._cfg.max_output_tokens is not None:
            params["max_completion_tokens"] = self._cfg.max_output_tokens
        resp = await self._client.chat.completions.create(
            model=self._model, messages=[{"role": "user", "content": content}], **params
        )
        choice = resp.choices[0] if resp.choices else None
        usage = resp.usage
        return _Answer(
            text=(choice.message.content if choice else None) or "",
            input_tokens=int(getattr(usage, "prompt_tokens", 0) or 0),
            output_tokens=int(getattr(usage, "completion_tokens", 0) or 0),
            extra={"finish_reason": getattr(choice, "finish_reason", None), "response_model": resp.model},
        )

    def is_transient(self, exc: BaseException) -> bool:
        return openai_is_transient(exc)

    def reached_server(self, exc: BaseException) -> bool:
        return openai_reached_server(exc)

    async def aclose(self) -> None:
        await self._client.close()


class _GeminiBackend:
    def __init__(self, model: str, base_url: str | None, api_key: str | None, cfg: "VLMConfig"):
        from google import genai
        from google.genai import types

        http = types.HttpOptions(
            timeout=int(cfg.timeout_s * 1000),  # milliseconds in this SDK
            retry_options=types.HttpRetryOptions(attempts=1),  # our loop retries, not the SDK
        )
        if base_url is not None:
            http.base_url = base_url
        # api_key=None lets the SDK read GOOGLE_API_KEY / GEMINI_API_KEY itself.
        self._client = genai.Client(api_key=api_key, http_options=http)
        self._types = types
        self._model = model
        self._cfg = cfg

    async def complete(self, prompt: str, images: list[bytes], mime: str) -> _Answer:
        t = self._types
        parts = [t.Part.from_text(text=prompt)]
        for label, data in zip(IMAGE_LABELS, images):
            parts += [t.Part.from_text(text=label), t.Part.from_bytes(data=data, mime_type=mime)]
        config = t.GenerateContentConfig(
            temperature=self._cfg.temperature, max_output_tokens=self._cfg.max_output_tokens
        )
        resp = await self._client.aio.models.generate_content(
            model=self._model, contents=[t.Content(role="user", parts=parts)], config=config
        )
        usage = resp.usage_metadata
        output = (getattr(usage, "candidates_token_count", 0) or 0) + (
            getattr(usage, "thoughts_token_count", 0) or 0  # thinking is billed as output
        )
        finish = resp.candidates[0].finish_reason if resp.candidates else None
        return _Answer(
            text=resp.text or "",
            input_tokens=int(getattr(usage, "prompt_token_count", 0) or 0),
            output_tokens=int(output),
            extra={"finish_reason": str(finish) if finish is not None else None},
        )

    def is_transient(self, exc: BaseException) -> bool:
        return gemini_is_transient(exc)

    def reached_server(self, exc: BaseException) -> bool:
        return gemini_reached_server(exc)

    async def aclose(self) -> None:
        await self._client.aio.aclose()


_BACKEND_CLASSES = {"openai": _OpenAIBackend, "gemini": _GeminiBackend}


def cache_key(backend: str, model: str, settings: dict, prompt: str, images: list[np.ndarray]) -> str:
    """sha256 over backend, model, generation settings, prompt text and the raw pixels.

    Raw pixels (with shape) rather than the encoded PNG, so a Pillow upgrade that changes
    compression does not empty the cache. Nothing secret (key, base URL) goes in.
    """
    h = hashlib.sha256()
    header = {"v": CACHE_FORMAT, "backend": backend, "model": model, "settings": settings, "prompt": prompt}
    h.update(json.dumps(header, sort_keys=True).encode())
    for img in images:
        arr = np.ascontiguousarray(img)
        h.update(f"|{arr.shape}|{arr.dtype}|".encode())
        h.update(arr.tobytes())
    return h.hexdigest()


# --------------------------------------------------------------------------- verifier


@dataclass
class VLMConfig:
    """Knobs of one VLM verifier. Holds no key: that lives only inside the SDK client."""

    backend: str
    model: str
    base_url: str | None = None
    timeout_s: float = 60.0  # bound on one HTTP attempt
    max_retries: int = 3  # extra attempts after the first, on transient errors only
    backoff_s: float = 1.0  # wait before the first retry; doubles each retry
    max_backoff_s: float = 30.0
    max_concurrency: int = 4  # requests in flight at once, per verifier and event loop
    cache_dir: str | Path | None = None  # None: no cache
    temperature: float | None = 0.0  # None: don't send (reasoning models reject it)
    max_output_tokens: int | None = None  # None: the server's default
    image_format: str = "png"  # "png" (lossless) or "jpeg" (smaller requests)

    def validate(self) -> None:
        if self.timeout_s <= 0:
            raise InvalidInput(f"timeout_s must be > 0, got {self.timeout_s}")
        if self.max_retries < 0:
            raise InvalidInput(f"max_retries must be >= 0, got {self.max_retries}")
        if self.backoff_s < 0 or self.max_backoff_s < 0:
            raise InvalidInput("backoff_s and max_backoff_s must be >= 0")
        if self.max_concurrency < 1:
            raise InvalidInput(f"max_concurrency must be >= 1, got {self.max_concurrency}")
        if self.image_format not in ("png", "jpeg"):
            raise InvalidInput(f"image_format must be 'png' or 'jpeg', got {self.image_format!r}")

    def backoff(self, retry: int) -> float:
        """Delay before retry number ``retry`` (0-based): backoff_s * 2**retry, capped."""
        return min(self.backoff_s * (2**retry), self.max_backoff_s)


@dataclass
class _LoopState:
    """Things bound to one asyncio event loop: the SDK's HTTP pool and the semaphore."""

    backend: _Backend
    semaphore: asyncio.Semaphore


class VLMVerifier:
    """Asks a VLM whether the predicted end state satisfies the sub-plan."""

    needs_images = True

    def __init__(self, config: VLMConfig, api_key: str | None = None, prices: dict | None = None):
        if config.backend not in BACKENDS:
            raise InvalidInput(f"unknown VLM backend {config.backend!r}; valid: {', '.join(BACKENDS)}")
        config.validate()
        require_sdk(config.backend)
        require_key(config.backend, api_key)
        self.config = config
        self.name = f"vlm:{config.backend}:{config.model}"
        self.prices = {**PRICES_PER_MTOK, **(prices or {})}
        self._secrets = Secrets(config.backend, api_key)
        # The key is captured in a closure so it is not an attribute anyone can print.
        self._new_backend = lambda: _BACKEND_CLASSES[config.backend](
            config.model, config.base_url, api_key, config
        )
        self._cache = ResponseCache(config.cache_dir) if config.cache_dir is not None else None
        self._loops: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        # Whether the server has ever answered (any HTTP status or timeout-free reply). Until it
        # has, a call whose every attempt failed to connect means nothing listens at the URL.
        self._reached = False

    def __repr__(self) -> str:
        return f"VLMVerifier({self.config!r})"

    def atoms_needed(self, request: VerifyRequest, objects: list[str]) -> list[str]:
        return []  # a VLM reads the pictures, not the privileged scene

    async def verify(self, request: VerifyRequest) -> Verdict:
        started = time.perf_counter()
        arrays = [request.first_agent, request.final_agent, request.final_wrist]
        names = ("first_agent", "final_agent", "final_wrist")
        fmt = self.config.image_format
        images = [encode_image(a, fmt, n) for a, n in zip(arrays, names)]
        prompt = build_prompt(request)
        key = cache_key(self.config.backend, self.config.model, self._settings(), prompt, arrays)

        if self._cache is not None and (hit := self._cache.get(key)) is not None:
            return self._from_cache(hit, key, started)

        state = self._loop_state()
        # The slot is held through backoff sleeps on purpose: under 429s this verifier slows
        # down instead of letting the waiting requests pile onto the server.
        async with state.semaphore:
            answer, attempts, error = await self._call_with_retries(state.backend, prompt, images)
        latency = time.perf_counter() - started
        if answer is None:
            return Verdict(
                success=None,
                rationale=f"verifier unavailable after {attempts} attempt(s): {error}",
                latency_s=latency,
                extra={"error": error, "attempts": attempts, "cached": False},
            )
        verdict = self._to_verdict(answer, latency, attempts)
        if self._cache is not None and verdict.success is not None:
            # Only real verdicts are cached: an unparseable answer is asked again next time.
            self._cache.put(key, self._cache_record(verdict))
        return verdict

    async def aclose(self) -> None:
        """Close the HTTP pool of the current event loop (optional; pools die with the loop)."""
        state = self._loops.pop(asyncio.get_running_loop(), None)
        if state is not None:
            await state.backend.aclose()

    # ---- internals

    def _settings(self) -> dict:
        c = self.config
        return {
            "temperature": c.temperature,
            "max_output_tokens": c.max_output_tokens,
            "image_format": c.image_format,
        }

    def _loop_state(self) -> _LoopState:
        # An SDK client's connection pool and an asyncio.Semaphore both belong to the loop
        # they were first used on; a caller that runs asyncio.run() twice gets fresh ones.
        loop = asyncio.get_running_loop()
        state = self._loops.get(loop)
        if state is None:
            state = _LoopState(self._new_backend(), asyncio.Semaphore(self.config.max_concurrency))
            self._loops[loop] = state
        return state

    async def _call_with_retries(
        self, backend: _Backend, prompt: str, images: list[bytes]
    ) -> tuple[_Answer | None, int, str]:
        """(answer, attempts, "") on success; (None, attempts, why) once transient errors use up
        the budget. Permanent errors raise VerifierCallError."""
        mime = f"image/{self.config.image_format}"
        error = ""
        attempts = 0
        connected = False  # some attempt of this call reached the server
        for retry in range(self.config.max_retries + 1):
            attempts += 1
            try:
                # wait_for is the hard bound; the SDK timeout alone may not cover every phase.
                call = backend.complete(prompt, images, mime)
                answer = await asyncio.wait_for(call, self.config.timeout_s)
                self._reached = True
                return answer, attempts, ""
            except (asyncio.TimeoutError, TimeoutError):
                error = f"timed out after {self.config.timeout_s:g} s"
                connected = True  # a hang is a slow server, not a missing one
            except Exception as exc:
                if backend.reached_server(exc):
                    connected = self._reached = True
                if not backend.is_transient(exc):
                    raise VerifierCallError(
                        f"{self.name}: request rejected ({self._describe(exc)}); "
                        "check the model name, base URL and API key"
                    ) from None  # no chained SDK exception: it may carry request headers
                error = self._describe(exc)
            if retry < self.config.max_retries:
                delay = self.config.backoff(retry)
                log.info("%s: attempt %d failed (%s); retrying in %.2f s", self.name, attempts, error, delay)
                await asyncio.sleep(delay)
        if not connected and not self._reached:
            # Never reached, not once since this verifier was made: a wrong URL or a server that
            # is down. Every later call would fail the same way, so this is not transient.
            raise VerifierCallError(self._secrets.scrub(
                f"{self.name}: cannot reach the server at {self.config.base_url or 'the SDK default URL'} "
                f"({attempts} attempt(s), last: {error}); is it running, and is the base URL right?"))
        log.warning("%s: giving up after %d attempt(s): %s", self.name, attempts, error)
        return None, attempts, error

    def _describe(self, exc: BaseException) -> str:
        status = getattr(exc, "status_code", None) or getattr(exc, "code", None)
        text = f"{type(exc).__name__}" + (f" HTTP {status}" if isinstance(status, int) else "")
        detail = str(exc).strip()
        if detail:
            text += f": {detail[:300]}"
        return self._secrets.scrub(text)

    def _to_verdict(self, answer: _Answer, latency: float, attempts: int) -> Verdict:
        raw = self._secrets.scrub(answer.text)
        parsed = parse_answer(raw)
        cost, note = cost_usd(self.config.model, answer.input_tokens, answer.output_tokens, self.prices)
        extra = {"cached": False, "attempts": attempts, **answer.extra}
        if note:
            extra["cost_note"] = note
        return Verdict(
            success=parsed.success,
            rationale=parsed.rationale,
            latency_s=latency,
            raw=raw,
            input_tokens=answer.input_tokens,
            output_tokens=answer.output_tokens,
            cost_usd=cost,
            extra=extra,
        )

    def _cache_record(self, verdict: Verdict) -> dict:
        record = asdict(verdict)
        record.pop("latency_s")
        record["backend"] = self.config.backend
        record["model"] = self.config.model
        return record

    def _from_cache(self, record: dict, key: str, started: float) -> Verdict:
        # A hit spends nothing now: tokens and cost are 0, what the first call spent is kept
        # in extra for reports.
        extra = dict(record.get("extra") or {})
        extra.update(
            cached=True,
            cache_key=key,
            original_input_tokens=record.get("input_tokens", 0),
            original_output_tokens=record.get("output_tokens", 0),
            original_cost_usd=record.get("cost_usd", 0.0),
        )
        return Verdict(
            success=record.get("success"),
            rationale=record.get("rationale", ""),
            latency_s=time.perf_counter() - started,
            raw=record.get("raw", ""),
            score=record.get("score"),
            extra=extra,
        )


def make_vlm_verifier(
    backend: str, model: str | None = None, base_url: str | None = None, **opts: Any
) -> VLMVerifier:
    """Build a VLM verifier. ``opts``: ``api_key``, ``prices`` and any :class:`VLMConfig` field
    (timeout_s, max_retries, backoff_s, max_backoff_s, max_concurrency, cache_dir,
    temperature, max_output_tokens, image_format)."""
    if backend not in BACKENDS:
        raise InvalidInput(f"unknown VLM backend {backend!r}; valid: {', '.join(BACKENDS)}")
    api_key = opts.pop("api_key", None)
    prices = opts.pop("prices", None)
    valid = set(VLMConfig.__dataclass_fields__) - {"backend", "model", "base_url"}
    unknown = sorted(set(opts) - valid)
    if unknown:
        valid_names = sorted(valid | {"api_key", "prices"})
        raise InvalidInput(f"unknown VLM verifier option(s) {unknown}; valid: {valid_names}")
    config = VLMConfig(backend=backend, model=model or DEFAULT_MODELS[backend], base_url=base_url, **opts)
    return VLMVerifier(config, api_key=api_key, prices=prices)
