"""Report plot of one capture step: depth, intensity, validity, temporal noise and plane residual maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from labctl.evaluation.capture import CaptureResult
from labctl.report.plots.png import save_png


def _limits(data: np.ndarray, symmetric: bool = False) -> tuple[float, float]:
    finite = data[np.isfinite(data)]
    if not finite.size:
        return 0.0, 1.0
    if symmetric:
        lim = float(np.quantile(np.abs(finite), 0.99)) or 1.0
        return -lim, lim
    lo, hi = (float(v) for v in np.quantile(finite, [0.01, 0.99]))
    return (lo, hi) if hi > lo else (lo - 0.5, hi + 0.5)


def plot_capture(result: CaptureResult, path: Path) -> Path:
    """The maps of one capture (imshow panels with colour bars and units)."""
    s = result.summary
    panels: list[tuple[str, np.ndarray, str, str, bool]] = [
        ("depth z, stack mean", s.depth, "mm", "viridis_r", False),
        ("temporal noise (per-pixel std of z)", s.noise, "mm", "magma", False),
        ("validity (fraction of frames)", s.validity, "", "gray", False),
    ]
    if s.intensity is not None:
        panels.insert(1, ("intensity, stack mean", s.intensity, "", "gray", False))
    if s.plane is not None and s.plane.planar:
        panels.append(("residual from the fitted plane", s.plane.residual, "mm", "RdBu_r", True))
    cols = 3
    rows = -(-len(panels) // cols)
    fig = Figure(figsize=(13, 3.9 * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    for ax, (title, data, unit, cmap, symmetric) in zip(axes.flat, panels):
        lo, hi = (0.0, 1.0) if title.startswith("validity") else _limits(data, symmetric)
        im = ax.imshow(data, cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest")
        ax.set_title(title)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, label=unit, shrink=0.85)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    fig.suptitle(f"Capture {result.step_id}: {s.frames} frame(s), {s.valid_fraction:.1%} valid pixels")
    fig.tight_layout()
    return save_png(fig, path, dpi=100)
