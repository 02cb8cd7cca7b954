"""A contact sheet per sub-plan round: every candidate's predicted end view with its verdict."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

COLORS = {True: (40, 170, 70), False: (200, 50, 50), None: (140, 140, 140)}


def label_font(size: int):
    """Pillow's scalable built-in font at ``size`` px, for every contact sheet we draw (the bitmap
    default squeezes the spaces out of "tomato sauce"); the bitmap one where Pillow lacks FreeType."""
    try:
        return ImageFont.load_default(size=size)
    except TypeError:
        return ImageFont.load_default()


def candidate_grid(images: list[np.ndarray], labels: list[str], verdicts: list[bool | None], path: Path,
                   title: str = "", columns: int = 5) -> Path:
    tile = images[0].shape[0] if images else 224
    pad, head = 6, 22
    rows = max(1, -(-len(images) // columns))
    cols = min(columns, max(1, len(images)))
    sheet = Image.new("RGB", (cols * (tile + 2 * pad), head + rows * (tile + 2 * pad + 16)), "white")
    draw = ImageDraw.Draw(sheet)
    font = label_font(14)
    draw.text((pad, 3), title[:120], fill=(0, 0, 0), font=font)
    for n, (img, label, ok) in enumerate(zip(images, labels, verdicts)):
        x = (n % cols) * (tile + 2 * pad)
        y = head + (n // cols) * (tile + 2 * pad + 16)
        draw.rectangle([x, y, x + tile + 2 * pad - 1, y + tile + 2 * pad - 1], fill=COLORS[ok])
        sheet.paste(Image.fromarray(img), (x + pad, y + pad))
        draw.text((x + pad, y + tile + 2 * pad), label[:40], fill=(0, 0, 0), font=font)
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)
    return path
