"""Figure of a Böhler-star evaluation (Thesis 2024, Fig. 5-6 and 6-6, 5.1.3), matplotlib Agg, PNG out."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from labctl.report.plots.png import save_png
from metrics.boehler import (
    MIN_SAMPLES_PER_SEGMENT,
    SECTOR_IS_V,
    BoehlerResult,
    sector_bounds,
    sectors,
    star_coordinates,
)

_RESOLVED, _UNRESOLVED, _OUTSIDE = "tab:green", "tab:red", "0.75"


def _ring_status(result: BoehlerResult, radius: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Per point: 1 its ring is resolved in its sector's orientation, 0 not, -1 not an evaluated ring."""
    ring = np.floor(radius / result.ring_width_mm).astype(np.int64)
    evaluated = ring < result.radii_mm.size
    sector, _ = sectors(angle, result.segments, math.radians(result.filled_phase_deg))
    ring = np.clip(ring, 0, result.radii_mm.size - 1)
    resolved = np.where(SECTOR_IS_V[sector], result.resolved_v[ring], result.resolved_h[ring])
    return np.where(evaluated, resolved.astype(int), -1)


def _label(name: str, radius: float, lateral: float, angular: float, clamped: bool) -> str:
    if math.isnan(radius):
        return f"{name}: not resolved"
    return f"{name}: r = {radius:.0f} mm, {lateral:.2f} mm, {angular:.3f} deg" + (" (sensor limit)" if clamped else "")


def plot_boehler(result: BoehlerResult, cloud: np.ndarray, path: Path) -> Path:
    """The star's inliers in its plane coloured by ring resolution, and clusters per ring for h and v.

    Left: inlier points in the star plane (as the camera sees them), green
    where their ring is resolved in their sector's orientation, red where
    not, grey outside the evaluated rings; the resolution radii as circles and
    the sector boundaries as lines. Right: inlier clusters per ring, scaled to
    the full circle, for the horizontal and vertical sectors and the whole
    ring, against the N/2 of a resolved ring; rings too sparse to count
    (fewer than 2 samples per segment) shaded.
    """
    radius, angle, inlier = star_coordinates(cloud, result)
    keep = inlier & (radius <= 1.05 * result.star_radius_mm)
    r, t = radius[keep], angle[keep]
    status = _ring_status(result, r, t)
    colours = np.array([_OUTSIDE, _UNRESOLVED, _RESOLVED])[status + 1]

    fig = Figure(figsize=(13, 6))

    ax, bx = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1, 1.25]})
    ax.scatter(r * np.cos(t), r * np.sin(t), c=colours, s=0.4, linewidths=0, rasterized=True)
    edge = result.star_radius_mm
    for bound in sector_bounds(result.segments, math.radians(result.filled_phase_deg)):
        ax.plot([0, edge * math.cos(bound)], [0, edge * math.sin(bound)], color="0.3", lw=0.8, ls=":")
    circle = np.linspace(0, 2 * math.pi, 361)
    for name, rad, style in (("h", result.radius_h_mm, "-"), ("v", result.radius_v_mm, "--")):
        if math.isfinite(rad):
            ax.plot(rad * np.cos(circle), rad * np.sin(circle), color="k", lw=1.0, ls=style, label=f"r_{name}")
    ax.set_aspect("equal")
    ax.set_xlabel("in-plane x (mm, camera right)")
    ax.set_ylabel("in-plane y (mm, camera up)")
    ax.set_title("inliers: green resolved, red not, grey not evaluated", fontsize=9)
    if math.isfinite(result.radius_h_mm) or math.isfinite(result.radius_v_mm):
        ax.legend(loc="upper right", fontsize=8)

    half = result.segments / 2
    rings = result.radii_mm + result.ring_width_mm / 2
    with np.errstate(invalid="ignore", divide="ignore"):
        scaled_h = result.clusters_h * half / result.expected_h
        scaled_v = result.clusters_v * half / result.expected_v
    bx.plot(rings, result.clusters, color="0.6", lw=0.8, label="whole ring")
    bx.plot(rings, scaled_h, color="tab:blue", lw=1.0, label="horizontal sectors (scaled to 360 deg)")
    bx.plot(rings, scaled_v, color="tab:orange", lw=1.0, label="vertical sectors (scaled to 360 deg)")
    bx.axhline(half, color="k", lw=0.8, ls=":", label=f"N/2 = {half:g} (resolved)")
    least = 2 * MIN_SAMPLES_PER_SEGMENT
    sparse = result.radii_mm[(result.points_h < least * result.expected_h) | (result.points_v < least * result.expected_v)]
    if sparse.size:
        bx.axvspan(0, sparse.max() + result.ring_width_mm, color="0.9", label="< 2 samples per segment")
    for rad, colour, style in ((result.radius_h_mm, "tab:blue", "-"), (result.radius_v_mm, "tab:orange", "--")):
        if math.isfinite(rad):
            bx.axvline(rad, color=colour, lw=1.0, ls=style)
    bx.set_ylim(0, 2.2 * half)
    bx.set_xlabel("ring radius (mm)")
    bx.set_ylabel("inlier clusters per ring")
    bx.set_title("\n".join([_label("h", result.radius_h_mm, result.resolution_h_mm, result.angular_h_deg,
                                   result.clamped_h),
                            _label("v", result.radius_v_mm, result.resolution_v_mm, result.angular_v_deg,
                                   result.clamped_v)]), fontsize=9)
    bx.grid(alpha=0.3)
    bx.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"Böhler star, {result.segments} segments, at {result.distance_mm:.0f} mm")
    fig.tight_layout()
    return save_png(fig, path, dpi=110)
