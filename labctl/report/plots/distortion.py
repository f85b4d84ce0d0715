"""Checkerboard distortion figure (Thesis 2024, Fig. 6-8): found and expected corners with magnified displacements."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from labctl.report.plots.png import save_png
from metrics.distortion import CloudDistortion, DistortionResult

_NICE = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)


def _magnification(displacement: np.ndarray, spacing: float) -> int:
    """Largest of 1, 2, 5, 10, ... that draws the longest displacement within 1.5 grid spacings."""
    longest = float(np.max(np.linalg.norm(displacement, axis=1))) if len(displacement) else 0.0
    if longest <= 0:
        return 1
    fitting = [m for m in _NICE if m * longest <= 1.5 * spacing]
    return fitting[-1] if fitting else 1


def _panel(ax, found: np.ndarray, expected: np.ndarray, ij: np.ndarray, width: float, label: str) -> int:
    """Found (red dots), expected (blue +) and (found - expected) x M arrows coloured by % of ``width``."""
    disp = found - expected
    spacing = float(np.ptp(expected[:, 0]) / np.ptp(ij[:, 0])) if np.ptp(ij[:, 0]) else 1.0
    m = _magnification(disp, spacing)
    magnitude = 100 * np.linalg.norm(disp, axis=1) / width
    ax.plot(expected[:, 0], expected[:, 1], "+", color="tab:blue", ms=4, label="expected")
    ax.plot(found[:, 0], found[:, 1], ".", color="tab:red", ms=3, label="found")
    arrows = ax.quiver(expected[:, 0], expected[:, 1], m * disp[:, 0], m * disp[:, 1], magnitude,
                       angles="xy", scale_units="xy", scale=1, cmap="plasma", width=0.003)
    ax.figure.colorbar(arrows, ax=ax, shrink=0.75, label=label)
    ax.legend(loc="upper right", fontsize=7)
    return m


def plot_distortion(image: np.ndarray, result: DistortionResult, path: Path,
                    cloud: CloudDistortion | None = None, title: str = "") -> Path:
    """Intensity image with its corners (and, if given, the cloud's corners in mm) like Thesis 2024, Fig. 6-8."""
    panels = 2 if cloud is not None else 1
    fig = Figure(figsize=(7.5 * panels, 5.6))
    axes = fig.subplots(1, panels, squeeze=False)
    ax = axes[0, 0]
    finite = image[np.isfinite(image)]
    lo, hi = np.quantile(finite, [0.01, 0.99]) if finite.size else (0.0, 1.0)
    ax.imshow(np.ma.masked_invalid(image), cmap="gray", vmin=lo, vmax=hi if hi > lo else lo + 1)
    height, width = image.shape
    m = _panel(ax, result.found, result.expected, result.ij, width, "|found - expected| (% of the image width)")
    if len(result.rejected_uv):
        ax.plot(result.rejected_uv[:, 0], result.rejected_uv[:, 1], "x", color="tab:orange", ms=6,
                label=f"left out ({len(result.rejected_uv)})")
        ax.legend(loc="upper right", fontsize=7)
    ax.set_title(f"intensity (vectors x{m}): raw {result.raw_distortion_w_pct:+.2f} / "
                 f"{result.raw_distortion_h_pct:+.2f} %, radial {result.radial_distortion_w_pct:+.2f} / "
                 f"{result.radial_distortion_h_pct:+.2f} %\nFOV estimate {result.fov_estimate_deg[0]:.1f} x "
                 f"{result.fov_estimate_deg[1]:.1f} deg, k1 {result.k1:+.4f}", fontsize=9)
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    if cloud is not None:
        ax = axes[0, 1]
        m = _panel(ax, cloud.found, cloud.expected, cloud.ij, cloud.extent_mm[0],
                   "|found - expected| (% of the view's width at the board)")
        ax.set_title(f"point cloud at z = {cloud.centre_z_mm:.0f} mm (vectors x{m}): "
                     f"{cloud.distortion_w_pct:+.2f} / {cloud.distortion_h_pct:+.2f} %", fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_aspect("equal")
        ax.invert_yaxis()
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_png(fig, path, dpi=100)
