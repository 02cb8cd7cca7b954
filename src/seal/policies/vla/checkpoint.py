"""A VLA checkpoint on disk: one directory, four files.

    model.safetensors   weights and the dataset statistics (buffers), fp32 or a 16-bit export
    config.json         `VLAConfig`: what shapes the network
    tokenizer.json      the BPE the model was trained with (`tokenizer.VLATokenizer`)
    manifest.json       written last (the commit, `seal.checkpoint`): kind, format, sha256 and size of
                        the three files above, dtype, parameter count, plus what the trainer adds
                        (data command, steps, code version, held-out figures)

Loading trusts nothing: the manifest must vouch for all three files and each must have the
recorded size and sha256 (`seal.checkpoint.verify`: a truncated, flipped or replaced file is
caught before it is parsed), the tokenizer's vocabulary must match the config, and every tensor
name and shape must be what the config builds. Each failure is an `InvalidInput` naming the file
and what is wrong. A 16-bit export is loaded back
to fp32 for inference (CPU bf16 matmuls are not uniformly faster, and fp32 keeps the Euler
integration of the flow accurate); `export_checkpoint` makes one for shipping.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from seal.checkpoint import atomic_write, file_digests, verify, write_manifest
from seal.checkpoint import read_manifest as _read_manifest
from seal.errors import InvalidInput
from seal.policies.vla.model import VLAConfig, VLAModel, count_parameters
from seal.policies.vla.tokenizer import VLATokenizer

from seal.policies.vla.locate import CONFIG, FILES, FORMAT, KIND, MANIFEST, TOKENIZER, WEIGHTS
DTYPES = {"fp32": torch.float32, "fp16": torch.float16, "bf16": torch.bfloat16}


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
    atomic_write(out / WEIGHTS, lambda p: save_file(tensors, str(p), metadata={"format": str(FORMAT), "kind": KIND}))
    atomic_write(out / CONFIG, lambda p: p.write_text(json.dumps(model.cfg.to_dict(), indent=2) + "\n"))
    atomic_write(out / TOKENIZER, lambda p: p.write_text(tokenizer.to_json()))
    # weights_sha256 stays beside "files": it has named the model in results stores from the start
    own = {"dtype": dtype, "params": count_parameters(model), "weights_sha256": file_digests(out / WEIGHTS)[0],
           "weights_bytes": (out / WEIGHTS).stat().st_size}
    write_manifest(out, kind=KIND, format=FORMAT, files=list(FILES), extra=own | (manifest or {}))
    return out


def read_manifest(path: Path) -> dict:
    """The manifest of a VLA checkpoint directory (its files are checked by `load_checkpoint`)."""
    manifest = _read_manifest(Path(path), kind=KIND)
    if manifest.get("format") != FORMAT:
        raise InvalidInput(f"{Path(path) / MANIFEST}: format {manifest.get('format')!r}; this loader reads format {FORMAT}")
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
    manifest = verify(path, kind=KIND, required=FILES)  # every byte checked before any is parsed
    read_manifest(path)  # the format
    cfg = read_config(path)
    tokenizer = VLATokenizer.load(path / TOKENIZER)
    if tokenizer.vocab_size != cfg.vocab_size:
        raise InvalidInput(f"{path / TOKENIZER} has {tokenizer.vocab_size} tokens but {CONFIG} says vocab_size "
                           f"{cfg.vocab_size}; they come from different runs")
    weights = path / WEIGHTS
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
    keep = {k: v for k, v in manifest.items()
            if k not in ("kind", "format", "files", "dtype", "weights_sha256", "weights_bytes", "params")}
    save_checkpoint(dst, model, tokenizer, {**keep, **(extra or {}), "exported_from": str(Path(src).resolve())},
                    dtype=dtype)
    return read_manifest(dst)
