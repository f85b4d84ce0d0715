"""Report plot of the vendors' depth-quality figures over the wall distance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from labctl.evaluation.depth_quality import VendorPosition
from labctl.report.plots.png import save_png


def plot_vendor_figures(positions: list[VendorPosition], path: Path) -> Path:
    """Fill rate, Z accuracy, plane-fit RMS / spatial / temporal precision and subpixel RMS over distance."""
    rows = sorted(positions, key=lambda p: p.reference_mm)
    d = np.array([p.reference_mm for p in rows])

    def series(attr: str) -> np.ndarray:
        return np.array([getattr(p.figures, attr) for p in rows])

    fig = Figure(figsize=(11, 7))

    axes = fig.subplots(2, 2, sharex=True)
    panels = [
        (axes[0, 0], "Fill rate (Depth Quality Tool ROI)", "%", [("fill_rate_pct", "fill rate")], "not measured"),
        (axes[0, 1], "Z accuracy (median signed error)", "% of distance", [("z_accuracy_pct", "Z accuracy")],
         "not measured: no absolute reference\n(devices.camera.depth_origin_offset_mm)"),
        (axes[1, 0], "Spatial and temporal noise", "mm", [("plane_fit_rms_mm", "plane-fit RMS (Intel)"),
                                                          ("spatial_precision_mm", "spatial precision (Basler)"),
                                                          ("temporal_precision_mm", "temporal precision (Basler)")],
         "not measured"),
        (axes[1, 1], "Subpixel RMS (stereo)", "px", [("subpixel_rms_px", "subpixel RMS")],
         "not measured (stereo cameras only)"),
    ]
    for ax, title, unit, attrs, why_empty in panels:
        for attr, label in attrs:
            values = series(attr)
            ax.plot(d, values, marker="o", ms=3, label=label)
            if not np.isfinite(values).any():
                ax.text(0.5, 0.5, why_empty, transform=ax.transAxes, ha="center")
                ax.set_yticks([])  # no made-up scale around nothing
        ax.set_title(title)
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
        ax.legend()
    axes[0, 0].set_ylim(0, 105)  # a fill rate of 100 % everywhere sits at the top, not mid-axis
    for ax in axes[1]:
        ax.set_xlabel("reference distance (mm)")
    fig.tight_layout()
    return save_png(fig, path, dpi=110)
