"""Report plot of the VDI/VDE 2634-2 measurements against their maximum permissible errors."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure

from labctl.evaluation.vdi2634 import QUANTITIES, AcceptanceResult, Measurement
from labctl.report.plots.png import save_png


def _position(m: Measurement) -> str:
    """A position's tick label: distance, the bar's orientation / tilt (spheres) or the plate's tilt."""
    pose = f"{m.pose_deg:g}/{m.tilt_deg:g}" if m.points_used else f"{m.pose_deg:g}"
    return f"{m.distance_mm:.0f} mm\n{pose} deg"


def plot_acceptance(result: AcceptanceResult, path: Path) -> Path:
    """Each measurement of each quantity over the positions (steps, labelled by distance and the bar's
    orientation / tilt towards the wall or the plate's tilt), the MPE as dashed lines."""
    names = [n for n in QUANTITIES if any(n in m.values for m in result.measurements)]
    fig = Figure(figsize=(4.2 * len(names), 3.8))
    axes = fig.subplots(1, len(names), squeeze=False)
    for ax, name in zip(axes[0], names):
        rows = [m for m in result.measurements if name in m.values]
        steps = list(dict.fromkeys(m.step_id for m in rows))
        ax.plot([steps.index(m.step_id) for m in rows], [m.values[name] for m in rows], "o", ms=3, alpha=0.6)
        mpe = result.mpe_mm.get(name)
        if mpe is not None:
            for level in ((mpe,) if QUANTITIES[name][1] == "max" else (mpe, -mpe)):
                ax.axhline(level, color="tab:red", linestyle="--", label="MPE")
        ax.set_xticks(range(len(steps)))
        ax.set_xticklabels([_position(m) for m in
                            (next(r for r in rows if r.step_id == s) for s in steps)], fontsize=7)
        ax.set_title(name.replace("_mm", " (mm)").replace("_", " "))
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_png(fig, path, dpi=100)
