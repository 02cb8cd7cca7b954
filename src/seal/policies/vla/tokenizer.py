"""A byte-level BPE tokenizer trained here, on the project's own text.

No pretrained tokenizer can be downloaded on this machine, and a general-purpose one (cl100k,
100k entries) would make the embedding table and the text head bigger than the whole rest of a
CPU-sized model. The VLA only ever reads LIBERO instructions and writes the three-field
reasoning (`seal.policies.base.Reasoning.text`), a vocabulary of a few hundred words, so a BPE
of ~1k entries trained on exactly that text turns most words into one token.

Byte-level pre-tokenization makes every string encodable (an unseen word falls back to byte
pieces instead of ``<unk>``) and makes ``decode(encode(text)) == text`` exact, which the
reasoning parser relies on. Training on the same text list always gives the same vocabulary.

The special tokens come first, with fixed ids, so the model code can name them.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable
from importlib import resources
from pathlib import Path

from seal.errors import InvalidInput
from seal.policies.base import ACT, THINK, Reasoning

PAD, BOS, EOS, UNK = "<pad>", "<bos>", "<eos>", "<unk>"
SPECIALS = (PAD, BOS, EOS, THINK, ACT, UNK)  # ids 0..5, in this order
DEFAULT_VOCAB = 1024


def _require():
    try:
        import tokenizers
    except ImportError as exc:
        raise InvalidInput("the VLA tokenizer needs the 'tokenizers' package: pip install 'tokenizers>=0.20'") from exc
    return tokenizers


class VLATokenizer:
    """Thin wrapper over a `tokenizers.Tokenizer` with the VLA's special tokens."""

    def __init__(self, tok) -> None:
        self._tok = tok
        ids = [tok.token_to_id(s) for s in SPECIALS]
        if ids != list(range(len(SPECIALS))):
            raise InvalidInput(f"tokenizer special tokens must be {list(SPECIALS)} with ids 0..{len(SPECIALS) - 1}; "
                               f"found ids {ids}")
        self.pad_id, self.bos_id, self.eos_id, self.think_id, self.act_id, self.unk_id = ids

    @property
    def vocab_size(self) -> int:
        return self._tok.get_vocab_size()

    def encode(self, text: str) -> list[int]:
        return self._tok.encode(text, add_special_tokens=False).ids

    def decode(self, ids: Iterable[int]) -> str:
        return self._tok.decode([int(i) for i in ids], skip_special_tokens=True)

    def to_json(self) -> str:
        return self._tok.to_str()

    def save(self, path: Path) -> None:
        Path(path).write_text(self.to_json())

    @classmethod
    def from_json(cls, text: str) -> VLATokenizer:
        tokenizers = _require()
        try:
            return cls(tokenizers.Tokenizer.from_str(text))
        except Exception as exc:  # the Rust side raises plain Exceptions with its parse message
            if isinstance(exc, InvalidInput):
                raise
            raise InvalidInput(f"not a valid tokenizer JSON: {exc}") from None

    @classmethod
    def load(cls, path: Path) -> VLATokenizer:
        path = Path(path)
        if not path.is_file():
            raise InvalidInput(f"tokenizer file {path} is missing")
        try:
            return cls.from_json(path.read_text())
        except InvalidInput as exc:
            raise InvalidInput(f"{path}: {exc}") from None


def train_tokenizer(texts: Iterable[str], vocab_size: int = DEFAULT_VOCAB) -> VLATokenizer:
    """A byte-level BPE over ``texts`` with ``SPECIALS`` as ids 0..5 (deterministic)."""
    tokenizers = _require()
    from tokenizers import decoders, models, pre_tokenizers, trainers

    texts = sorted({t for t in texts if t})  # order-independent: the same set gives the same merges
    if not texts:
        raise InvalidInput("no text to train the tokenizer on")
    tok = tokenizers.Tokenizer(models.BPE(unk_token=UNK))
    tok.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    tok.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(vocab_size=vocab_size, special_tokens=list(SPECIALS), show_progress=False,
                                  initial_alphabet=pre_tokenizers.ByteLevel.alphabet())
    tok.train_from_iterator(texts, trainer=trainer)
    return VLATokenizer(tok)


def project_texts() -> list[str]:
    """The text every VLA tokenizer sees besides its dataset's: all suite instructions
    (src/seal/data/instructions.csv) and the fixed words of the reasoning format."""
    with resources.files("seal").joinpath("data/instructions.csv").open() as f:
        instructions = [row["instruction"] for row in csv.DictReader(f)]
    template = [Reasoning(plans=("a", "b"), done=(), now="a").text(),
                Reasoning(plans=("a", "b"), done=("a", "b"), now="").text()]
    return instructions + template
