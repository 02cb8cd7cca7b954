"""The client side of every vision-language-model call SEAL makes: the VLM verifier
(`seal.verify.vlm`), the reasoning annotator (`seal.annotate.backends`) and the VLM planner
(`seal.policies.planners`) share it, so all three guard keys, check SDKs, classify retries,
cache answers, price calls and encode images the same way.

Keys come from the environment (or an explicit argument) and are never stored outside the SDK
client: `Secrets` only remembers them to blank them out of any text that leaves a module.
"""

from __future__ import annotations

import io
import json
import logging
import os
import re
import tempfile
from pathlib import Path

import numpy as np

from seal.errors import InvalidInput

log = logging.getLogger(__name__)

BACKENDS = ("openai", "gemini")
DEFAULT_MODELS = {"openai": "gpt-4o", "gemini": "gemini-2.5-pro"}
SDK_PACKAGES = {"openai": "openai", "gemini": "google-genai"}

# The env vars each SDK reads for its key, in the SDK's own order of precedence.
KEY_ENV_VARS = {"openai": ("OPENAI_API_KEY",), "gemini": ("GOOGLE_API_KEY", "GEMINI_API_KEY")}

# USD per 1M tokens, (input, output), list prices of the providers' standard (non-batch)
# tiers as of mid-2025. Gemini 2.5 Pro costs more above 200k prompt tokens; a verifier prompt
# is ~1k tokens, so the lower tier is the one that applies. Gemini "thinking" tokens are billed
# as output and are counted as output below. A model missing here costs 0 and the verdict
# says so in ``extra["cost_note"]``; pass ``prices=`` to the verifier to add or override.
PRICES_PER_MTOK: dict[str, tuple[float, float]] = {
    "gpt-4o": (2.50, 10.00),
    "gpt-4o-mini": (0.15, 0.60),
    "gpt-4.1": (2.00, 8.00),
    "gpt-4.1-mini": (0.40, 1.60),
    "gpt-4.1-nano": (0.10, 0.40),
    "o4-mini": (1.10, 4.40),
    "gpt-5": (1.25, 10.00),
    "gpt-5-mini": (0.25, 2.00),
    "gemini-2.5-pro": (1.25, 10.00),
    "gemini-2.5-flash": (0.30, 2.50),
    "gemini-2.5-flash-lite": (0.10, 0.40),
    "gemini-2.0-flash": (0.10, 0.40),
}

# --------------------------------------------------------------------------- cost


def price_for(model: str, prices: dict[str, tuple[float, float]]) -> tuple[float, float] | None:
    """Exact name, else the longest table name that the model extends with a version suffix
    (``gpt-4o-2024-08-06`` -> ``gpt-4o``; ``gpt-4o-mini`` stays its own entry)."""
    name = model.removeprefix("models/")
    if name in prices:
        return prices[name]
    best = None
    for key in prices:
        rest = name[len(key) :]
        if name.startswith(key) and re.match(r"^-\d", rest) and (best is None or len(key) > len(best)):
            best = key
    return prices[best] if best else None


def cost_usd(model: str, input_tokens: int, output_tokens: int, prices: dict) -> tuple[float, str]:
    price = price_for(model, prices)
    if price is None:
        return 0.0, f"no price for model {model!r}; cost counted as 0"
    return (input_tokens * price[0] + output_tokens * price[1]) / 1e6, ""


# --------------------------------------------------------------------------- images


def encode_image(image: np.ndarray | None, fmt: str, what: str) -> bytes:
    if image is None:
        raise InvalidInput(f"the VLM verifier needs request.{what} (an HxWx3 uint8 image), got None")
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise InvalidInput(
            f"request.{what} must be an HxWx3 uint8 image, got shape {arr.shape} dtype {arr.dtype}"
        )
    from PIL import Image

    buf = io.BytesIO()
    if fmt == "png":
        Image.fromarray(arr).save(buf, format="PNG")
    else:
        Image.fromarray(arr).save(buf, format="JPEG", quality=95)
    return buf.getvalue()


# --------------------------------------------------------------------------- secrets


class Secrets:
    """The key values a client could send, kept only to blank them out of any text."""

    def __init__(self, backend: str, explicit_key: str | None):
        values = [explicit_key] + [os.environ.get(v) for v in KEY_ENV_VARS[backend]]
        self._values = [v for v in values if v and len(v) >= 4]

    def scrub(self, text: str) -> str:
        for v in self._values:
            text = text.replace(v, "***")
        return text

    def __repr__(self) -> str:  # never show the values, even in a debugger dump
        return f"<{len(self._values)} secret(s)>"


# --------------------------------------------------------------------------- retries


def openai_is_transient(exc: BaseException) -> bool:
    """Whether an openai SDK error is worth retrying (connection trouble, timeouts, 429, 5xx)."""
    import openai

    if isinstance(exc, openai.APIConnectionError):  # includes APITimeoutError
        return True
    if isinstance(exc, openai.APIStatusError):
        return status_is_transient(exc.status_code)
    return isinstance(exc, transport_errors())


def openai_reached_server(exc: BaseException) -> bool:
    """Whether the server answered at all (any HTTP status) or at least took the connection and
    went quiet (a timeout), as opposed to a connection that failed."""
    import openai

    return isinstance(exc, (openai.APIStatusError, openai.APITimeoutError))


def gemini_reached_server(exc: BaseException) -> bool:
    from google.genai import errors

    timeouts = tuple(t for t in transport_errors() if "Timeout" in t.__name__)
    return isinstance(exc, (errors.APIError, *timeouts))


def gemini_is_transient(exc: BaseException) -> bool:
    """Whether a google-genai error is worth retrying (transport trouble, 429, 5xx)."""
    from google.genai import errors

    if isinstance(exc, errors.APIError):
        return status_is_transient(exc.code)
    return isinstance(exc, transport_errors())


def status_is_transient(status: int | None) -> bool:
    return status is not None and (status in (408, 429) or status >= 500)


def transport_errors() -> tuple[type[BaseException], ...]:
    """Connection-level errors of whichever HTTP stack the SDKs picked (httpx, httpx2, aiohttp)."""
    found: list[type[BaseException]] = [ConnectionError, TimeoutError]
    for module, names in (
        ("httpx", ("TransportError",)),
        ("httpx2", ("TransportError",)),
        ("aiohttp", ("ClientConnectionError", "ServerTimeoutError")),
    ):
        try:
            mod = __import__(module)
        except ImportError:
            continue
        found += [getattr(mod, n) for n in names if hasattr(mod, n)]
    return tuple(found)


# --------------------------------------------------------------------------- cache


class ResponseCache:
    """One JSON file per verdict under ``root/ab/abcdef....json``; writes are atomic renames."""

    def __init__(self, root: str | Path):
        self.root = Path(root)

    def _path(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.json"

    def get(self, key: str) -> dict | None:
        path = self._path(key)
        try:
            return json.loads(path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as exc:  # a torn or foreign file is a miss, not a crash
            log.warning("ignoring unreadable cache entry %s: %s", path, exc)
            return None

    def put(self, key: str, record: dict) -> None:
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(record, f, indent=1)
        os.replace(tmp, path)


# --------------------------------------------------------------------------- SDKs and keys


def require_sdk(backend: str) -> None:
    try:
        if backend == "openai":
            import openai  # noqa: F401
        else:
            from google import genai  # noqa: F401
    except ImportError as exc:
        raise InvalidInput(
            f"the {backend!r} VLM backend needs the {SDK_PACKAGES[backend]!r} package: "
            f"pip install {SDK_PACKAGES[backend]}"
        ) from exc


def require_key(backend: str, api_key: str | None) -> None:
    if api_key or any(os.environ.get(v) for v in KEY_ENV_VARS[backend]):
        return
    names = " or ".join(KEY_ENV_VARS[backend])
    hint = " (any non-empty value for a local server that ignores it)" if backend == "openai" else ""
    raise InvalidInput(f"no API key for the {backend!r} VLM backend: set {names}{hint}, or pass api_key=")
