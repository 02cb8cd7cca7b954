"""A VLA checkpoint on disk: one directory, four files.

    model.safetensors   weights and the dataset statistics (buffers), fp32 or a 16-bit export
    config.json         `VLAConfig`: what shapes the network
    tokenizer.json      the BPE the model was trained with (`tokenizer.VLATokenizer`)
    manifest.json       written last (the commit): format, dtype, parameter count, sha256 and size
                        of model.safetensors, plus what the trainer adds (data command, steps, code
                        version, held-out figures)

Loading trusts nothing: every file must be there and parse, the tokenizer's vocabulary must
match the config, the weights' sha256 must match the manifest (a truncated or replaced file is
caught before it is read), and every tensor name and shape must be what the config builds. Each
failure is an `InvalidInput` naming the file and what is wrong. A 16-bit export is loaded back
to fp32 for inference (CPU bf16 matmuls are not uniformly faster, and fp32 keeps the Euler
integration of the flow accurate); `export_checkpoint` makes one for shipping.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import torch

from seal.errors import InvalidInput
from seal.policies.vla.model import VLAConfig, VLAModel, count_parameters
from seal.policies.vla.tokenizer import VLATokenizer

FORMAT = 1
KIND = "seal-vla"
WEIGHTS, CONFIG, TOKENIZER, MANIFEST = "model.safetensors", "config.json", "tokenizer.json", "manifest.json"
DTYPES = {"fp32": torch.float32, "fp16": torch.float16, "bf16": torch.bfloat16}


def _write(path: Path, write) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def save_checkpoint(out: Path, model: VLAModel, tokenizer: VLATokenizer, manifest: dict | None = None,
                    *, dtype: str = "fp32") -> Path:
    """Write ``model`` (weights cast to ``dtype``), its config, tokenizer and manifest to ``out``."""
    from safetensors.torch import save_file

    if dtype not in DTYPES:
        raise InvalidInput(f"unknown checkpoint dtype {dtype!r}; valid: {', '.join(DTYPES)}")
    if tokenizer.vocab_size != model.cfg.vocab_size:
        raise InvalidInput(f"tokenizer has {tokenizer.vocab_size} tokens, the model {model.cfg.vocab_size}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / MANIFEST).unlink(missing_ok=True)  # no manifest = no checkpoint, until this one is complete
    tensors = {k: (v.to(DTYPES[dtype]) if v.is_floating_point() else v).detach().cpu().contiguous()
               for k, v in model.state_dict().items()}
    _write(out / WEIGHTS, lambda p: save_file(tensors, str(p), metadata={"format": str(FORMAT), "kind": KIND}))
    _write(out / CONFIG, lambda p: p.write_text(json.dumps(model.cfg.to_dict(), indent=2) + "\n"))
    _write(out / TOKENIZER, lambda p: p.write_text(tokenizer.to_json()))
    record = {"format": FORMAT, "kind": KIND, "dtype": dtype, "params": count_parameters(model),
              "weights_sha256": _sha256(out / WEIGHTS), "weights_bytes": (out / WEIGHTS).stat().st_size,
              **(manifest or {})}
    _write(out / MANIFEST, lambda p: p.write_text(json.dumps(record, indent=2) + "\n"))
    return out


def read_manifest(path: Path) -> dict:
    path = Path(path)
    file = path / MANIFEST
    if not file.is_file():
        raise InvalidInput(f"{path} is not a complete VLA checkpoint: {MANIFEST} is missing (an interrupted save, "
                           f"or not a checkpoint directory)")
    try:
        manifest = json.loads(file.read_text())
    except json.JSONDecodeError as exc:
        raise InvalidInput(f"{file} is not valid JSON ({exc})") from None
    if manifest.get("kind") != KIND or manifest.get("format") != FORMAT:
        raise InvalidInput(f"{file}: kind {manifest.get('kind')!r} format {manifest.get('format')!r}; "
                           f"this loader reads kind {KIND!r} format {FORMAT}")
    return manifest


def read_config(path: Path) -> VLAConfig:
    """The network's shape from a checkpoint directory's config.json (no weights are read)."""
    path = Path(path)
    try:
        return VLAConfig.from_dict(json.loads((path / CONFIG).read_text()))
    except FileNotFoundError:
        raise InvalidInput(f"VLA checkpoint {path} lacks {CONFIG}") from None
    except json.JSONDecodeError as exc:
        raise InvalidInput(f"{path / CONFIG} is not valid JSON ({exc})") from None
    except (TypeError, InvalidInput) as exc:
        raise InvalidInput(f"{path / CONFIG}: {exc}") from None


def load_checkpoint(path: Path, *, device: str | torch.device = "cpu") -> tuple[VLAModel, VLATokenizer, dict]:
    """(model in eval mode on ``device``, tokenizer, manifest); InvalidInput for anything wrong."""
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    if not path.is_dir():
        raise InvalidInput(f"no VLA checkpoint directory at {path}")
    manifest = read_manifest(path)
    missing = [name for name in (WEIGHTS, CONFIG, TOKENIZER) if not (path / name).is_file()]
    if missing:
        raise InvalidInput(f"VLA checkpoint {path} lacks {', '.join(missing)}")
    cfg = read_config(path)
    tokenizer = VLATokenizer.load(path / TOKENIZER)
    if tokenizer.vocab_size != cfg.vocab_size:
        raise InvalidInput(f"{path / TOKENIZER} has {tokenizer.vocab_size} tokens but {CONFIG} says vocab_size "
                           f"{cfg.vocab_size}; they come from different runs")
    weights = path / WEIGHTS
    size = weights.stat().st_size
    if "weights_bytes" in manifest and size != manifest["weights_bytes"]:
        raise InvalidInput(f"{weights} is {size} bytes but the manifest says {manifest['weights_bytes']}: the file "
                           f"is truncated or was replaced")
    if "weights_sha256" in manifest and _sha256(weights) != manifest["weights_sha256"]:
        raise InvalidInput(f"{weights} does not match the sha256 in {MANIFEST}: the file is corrupt or was replaced")
    model = VLAModel(cfg)
    expected = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    try:
        with safe_open(str(weights), framework="pt") as f:
            found = {k: tuple(f.get_slice(k).get_shape()) for k in f.keys()}
            problems = _shape_problems(expected, found)
            if problems:
                raise InvalidInput(f"{weights} does not fit {CONFIG}: " + "; ".join(problems))
            state = {k: f.get_tensor(k) for k in f.keys()}
    except SafetensorError as exc:
        raise InvalidInput(f"{weights} is not a readable safetensors file ({exc}); it may be truncated") from None
    state = {k: v.float() if v.is_floating_point() else v for k, v in state.items()}
    model.load_state_dict(state, strict=True)
    return model.to(device).eval(), tokenizer, manifest


def _shape_problems(expected: dict, found: dict, limit: int = 6) -> list[str]:
    out = [f"tensor {k!r} is missing" for k in sorted(set(expected) - set(found))]
    out += [f"unexpected tensor {k!r}" for k in sorted(set(found) - set(expected))]
    out += [f"tensor {k!r} has shape {list(found[k])}, the config wants {list(expected[k])}"
            for k in sorted(set(expected) & set(found)) if expected[k] != found[k]]
    if len(out) > limit:
        out = out[:limit] + [f"... {len(out) - limit} more"]
    return out


def export_checkpoint(src: Path, dst: Path, *, dtype: str = "bf16", extra: dict | None = None) -> dict:
    """A copy of checkpoint ``src`` with 16-bit weights for shipping; returns its manifest."""
    model, tokenizer, manifest = load_checkpoint(src)
    keep = {k: v for k, v in manifest.items() if k not in ("dtype", "weights_sha256", "weights_bytes", "params")}
    save_checkpoint(dst, model, tokenizer, {**keep, **(extra or {}), "exported_from": str(Path(src).resolve())},
                    dtype=dtype)
    return read_manifest(dst)
