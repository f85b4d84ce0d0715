"""Console frames as PNG: a decimated depth or intensity image, colour-mapped, with the evaluation region
or the alignment's corner fields outlined."""

from __future__ import annotations

import io

import numpy as np
from matplotlib import colormaps
from PIL import Image

Box = tuple[int, int, int, int]
"""A region to outline, in decimated pixels: top, left, bottom, right (exclusive)."""

OUTLINE = np.array([255, 64, 160], dtype=np.uint8)


def decimate(image: np.ndarray, max_width: int) -> tuple[np.ndarray, int]:
    """Every n-th pixel of ``image`` in both directions so it is at most ``max_width`` wide (a copy), and n."""
    factor = max(1, -(-image.shape[1] // max_width))
    return np.array(image[::factor, ::factor], dtype=np.float32), factor


def to_png(image: np.ndarray, cmap: str, boxes: list[Box]) -> bytes:
    """``image`` colour-mapped between its 2nd and 98th percentile (NaN black) with ``boxes`` outlined, as PNG."""
    finite = image[np.isfinite(image)]
    lo, hi = (np.percentile(finite, [2, 98]) if finite.size else (0.0, 1.0))
    scaled = np.clip((image - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    rgb = (colormaps[cmap](np.nan_to_num(scaled, nan=0.0))[..., :3] * 255).astype(np.uint8)
    rgb[~np.isfinite(image)] = 0
    height, width = image.shape
    for top, left, bottom, right in boxes:
        top, left = max(top, 0), max(left, 0)
        bottom, right = min(max(bottom, top + 1), height), min(max(right, left + 1), width)
        rgb[top, left:right] = rgb[bottom - 1, left:right] = OUTLINE
        rgb[top:bottom, left] = rgb[top:bottom, right - 1] = OUTLINE
    out = io.BytesIO()
    Image.fromarray(rgb).save(out, format="PNG")
    return out.getvalue()


def scaled_box(rows: slice, cols: slice, factor: int) -> Box:
    """A region of full-resolution pixels in decimated pixels."""
    return rows.start // factor, cols.start // factor, -(-rows.stop // factor), -(-cols.stop // factor)
