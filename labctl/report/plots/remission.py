"""Plots of the remission-and-angle evaluation (Thesis 2024, Fig. 6-11, Fig. 5-15), matplotlib Agg, PNG out."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from labctl.evaluation.remission import RemissionResult
from labctl.report.plots.png import save_png

COLORS = {"ptfe": "tab:blue", "molleton": "black", "silicone": "tab:orange", "gelatine": "tab:green",
          "collagen": "tab:red"}


def plot_remission(result: RemissionResult, path: Path) -> Path:
    """Per material over the robot angle: repeatability, trueness vs 0 deg and vs the geometric reference.

    Steps whose ROI is not on the target are left out (Thesis 2024, 6.5.1).
    """
    fig = Figure(figsize=(16, 4.8))
    axes = fig.subplots(1, 3, sharex=True)
    panels = [
        (axes[0], "Repeatability (pooled std over the ROI)", lambda r: r.roi.repeatability_mm),
        (axes[1], "Trueness vs the material's 0 deg distance", lambda r: r.trueness_zero_mm),
        (axes[2], "Trueness vs the geometric reference", lambda r: r.trueness_geometric_mm),
    ]
    for material in result.materials:
        rows = [r for r in result.material_rows(material) if r.roi.on_target]
        angles = [r.angle_deg for r in rows]
        for ax, _, value in panels:
            ax.plot(angles, [value(r) for r in rows], marker="o", ms=3, label=material,
                    color=COLORS.get(material))
    for ax, title, _ in panels:
        ax.set_title(title)
        ax.set_xlabel("robot angle (deg)")
        ax.set_ylabel("mm")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fit = result.fit
    reference = (f"{result.fit_material} fit: target {fit.delta_mm:+.1f} mm, camera axis {fit.e_mm:+.1f} mm"
                 if fit else "no misalignment fit: reference = commanded radius")
    fig.suptitle(f"Remission and angle, ROI {result.roi[2]}x{result.roi[3]} px on the optical axis; {reference}")
    fig.tight_layout()
    return save_png(fig, path, dpi=110)


def _signed_term(value: float, text: str) -> str:
    """`` + 1.23 text`` or `` - 1.23 text``; a value that rounds to 0.00 gets a plus (never "-0.00")."""
    rounded = round(value, 2) or 0.0
    return f" {'-' if rounded < 0 else '+'} {abs(rounded):.2f}{text}"


def misalignment_label(bias_mm: float, delta_mm: float, e_mm: float) -> str:
    """Legend of the fitted curve b + delta / cos(theta) - e tan(theta) with its numbers, signs folded in."""
    b, d, e = (round(v, 2) or 0.0 for v in (bias_mm, delta_mm, e_mm))  # "or 0.0": -0.0 prints as 0.0
    return f"fit: {b:.2f}{_signed_term(d, '/cos θ')}{_signed_term(-e, ' tan θ')} mm\n(b {b:+.2f}, δ {d:+.2f}, e {e:+.2f} mm)"


def plot_misalignment_fit(result: RemissionResult, path: Path) -> Path:
    """Measured axis distance minus radius of the fit material against b + delta/cos - e tan, and residuals."""
    fit = result.fit
    if fit is None:
        raise ValueError("the result has no misalignment fit to plot")
    rows = [r for r in result.material_rows(result.fit_material) if r.roi.on_target]
    angles = np.array([r.angle_deg for r in rows])
    measured = np.array([r.roi.distance_mm - r.radius_mm for r in rows])
    se = np.array([r.roi.distance_se_mm for r in rows])
    grid = np.linspace(angles.min(), angles.max(), 200)
    t = np.radians(grid)
    fig = Figure(figsize=(8, 7))
    top, bottom = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2.2, 1]})
    top.errorbar(angles, measured, yerr=se, fmt="o", ms=4, color="tab:blue", label=f"{result.fit_material} measured")
    top.plot(grid, fit.bias_mm + fit.delta_mm / np.cos(t) - fit.e_mm * np.tan(t), color="tab:red",
             label=misalignment_label(fit.bias_mm, fit.delta_mm, fit.e_mm))
    top.plot(grid, fit.bias_mm + fit.delta_mm / np.cos(t), ls="--", color="tab:purple", label="target term")
    top.plot(grid, fit.bias_mm + fit.delta_mm - fit.e_mm * np.tan(t), ls=":", color="tab:green",
             label="camera-axis term")
    top.set_ylabel("axis distance - radius (mm)")
    top.set_title(f"Misalignment (Thesis 2024, Fig. 5-15): target {fit.delta_mm:+.2f} +- {fit.delta_se_mm:.2f} mm, "
                  f"camera axis {fit.e_mm:+.2f} +- {fit.e_se_mm:.2f} mm", fontsize=10)
    top.grid(alpha=0.3)
    top.legend(fontsize=8)
    bottom.plot(fit.angles_deg, fit.residuals_mm, marker="o", ms=4, color="tab:blue")
    bottom.axhline(0.0, color="grey", lw=0.8)
    bottom.set_ylabel("residual (mm)")
    bottom.text(0.01, 0.92, f"RMS {fit.residual_rms_mm:.2f} mm", transform=bottom.transAxes, va="top", fontsize=8)
    bottom.set_xlabel("robot angle (deg)")
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    return save_png(fig, path, dpi=110)
