"""Report plots (matplotlib, Agg backend): one function per figure, PNG out."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from labctl.evaluation.evaluate import DepthPosition, SurfaceResult
from labctl.evaluation.sharpness import SharpnessResult
from labctl.report.plots.png import save_png
from metrics.xy_error import XYPrecision


def plot_depth_curves(depth: list[DepthPosition], path: Path) -> Path:
    """Trueness, accuracy, precision (median and Q90 of |.|) and invalid fraction over distance."""
    d = np.array([p.errors.reference_mm for p in depth])
    order = np.argsort(d)
    d = d[order]

    def series(attr: str) -> np.ndarray:
        return np.array([getattr(depth[i].errors, attr) for i in order])

    fig = Figure(figsize=(11, 7.5))

    axes = fig.subplots(2, 2, sharex=True)
    panels = [
        (axes[0, 0], "Trueness |mean - reference|", ["trueness_median_mm", "trueness_q90_mm"]),
        (axes[0, 1], "Accuracy |single frame - reference|", ["accuracy_median_mm", "accuracy_q90_mm"]),
        (axes[1, 0], "Precision (per-pixel std)", ["precision_median_mm", "precision_q90_mm", "repeatability_center_mm"]),
    ]
    labels = {"median": "median", "q90": "Q90", "center": "centre pixel"}
    for ax, title, attrs in panels:
        for attr in attrs:
            tag = next(k for k in labels if k in attr)
            ax.plot(d, series(attr), marker="o", ms=3, label=labels[tag])
        ax.set_title(title)
        ax.set_ylabel("mm")
        ax.grid(alpha=0.3)
        ax.legend()
    ax = axes[1, 1]
    invalid_pct = 100 * series("invalid_fraction")
    ax.plot(d, invalid_pct, marker="o", ms=3, color="tab:red")
    ax.set_ylim(*percent_axis_limits(invalid_pct))
    ax.set_title("Invalid pixels")
    ax.set_ylabel("% of the image")
    ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("reference distance (mm)")
    fig.tight_layout()
    return save_png(fig, path, dpi=110)


def percent_axis_limits(values_pct: np.ndarray) -> tuple[float, float]:
    """A percentage axis from 0 to at least 1 % (so all-zero data sits on the floor, not mid-axis), 10 % headroom."""
    finite = values_pct[np.isfinite(values_pct)]
    top = float(finite.max()) if finite.size else 0.0
    return 0.0, min(100.0, max(1.0, 1.1 * top))


def plot_xy_noise(precision: list[tuple[str, float, XYPrecision]], path: Path) -> Path:
    """x and y precision (Q90 of the per-pixel std) and the repeatability of the off-axis and the centre pixel over
    distance (Thesis 2024, 5.3; the off-axis pixel: docs/metrics.md, x/y noise)."""
    rows = sorted(precision, key=lambda item: item[1])
    d = np.array([distance for _, distance, _ in rows])
    fig = Figure(figsize=(11, 3.8))
    axes = fig.subplots(1, 2, sharex=True)
    for ax, axis in zip(axes, "xy"):
        ax.plot(d, [getattr(p, f"precision_q90_{axis}_mm") for *_, p in rows], marker="o", ms=3, label="Q90 over pixels")
        ax.plot(d, [getattr(p, f"repeatability_off_axis_{axis}_mm") for *_, p in rows], marker="o", ms=3,
                label=f"off-axis pixel (halfway to the {'right' if axis == 'x' else 'bottom'} edge)")
        ax.plot(d, [getattr(p, f"repeatability_center_{axis}_mm") for *_, p in rows], marker="o", ms=3,
                label=f"centre pixel ({axis} ~ 0: no depth noise)")
        ax.set_title(f"{axis} noise (per-pixel std over the stack)")
        ax.set_xlabel("distance (mm)")
        ax.set_ylabel("mm")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    return save_png(fig, path, dpi=110)


def plot_surface_maps(surface: SurfaceResult, path: Path) -> Path:
    """Primary, waviness and roughness surfaces with their Sq, symmetric colour scales."""
    t = surface.texture
    fig = Figure(figsize=(15, 4.2))
    axes = fig.subplots(1, 3)
    for ax, (name, data, sq) in zip(
        axes,
        [("primary", t.primary, t.sq_primary_mm), ("waviness", t.waviness, t.sq_waviness_mm),
         ("roughness", t.roughness, t.sq_roughness_mm)],
    ):
        finite = data[np.isfinite(data)]
        lim = float(np.quantile(np.abs(finite), 0.995)) if finite.size else 1.0
        lim = lim if math.isfinite(lim) and lim > 0 else 1.0
        im = ax.imshow(data, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
        ax.set_title(f"{name} surface, Sq = {sq:.3f} mm")
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, label="mm", shrink=0.85)
    fig.suptitle(
        f"Surface texture at {surface.reference_mm:.0f} mm ({surface.step_id}), cut-off {t.cutoff_mm:g} mm"
    )
    fig.tight_layout()
    return save_png(fig, path, dpi=110)


def _valid_and_invalid(ax, d: np.ndarray, v: np.ndarray, ok: np.ndarray, label: str, color: str) -> None:
    """A solid line through the valid points only; invalid points hollow, invalid positions without a value
    as crosses along the bottom: the same valid/invalid split as the table (whose note gives the reason)."""
    finite = np.isfinite(v)
    good = ok & finite
    ax.plot(d[good], v[good], marker="o", ms=3, color=color, label=label)
    bad = finite & ~ok
    ax.plot(d[bad], v[bad], linestyle="none", marker="o", ms=5, mfc="none", color=color)
    missing = ~finite
    ax.plot(d[missing], np.full(int(missing.sum()), 0.03), linestyle="none", marker="x", color=color,
            transform=ax.get_xaxis_transform())


def plot_sharpness(result: SharpnessResult, path: Path) -> Path:
    """SFR10, SFR50 and SFR area over distance, horizontal and vertical (Thesis 2024, Fig. 6-3)."""
    fig = sharpness_figure(result)
    return save_png(fig, path, dpi=110)


def sharpness_figure(result: SharpnessResult) -> Figure:
    """The figure of :func:`plot_sharpness`: one legend under the three plots, never on their data, naming the
    orientations, the Nyquist frequency, the hyperfocal and best-focus lines and how invalid positions are drawn."""
    fig = Figure(figsize=(15, 4.6))
    axes = fig.subplots(1, 3, sharex=True)
    lines = ((result.hyperfocal_mm, "hyperfocal", ":"), (result.best_focus_mm, "best focus", "-."))
    for ax, attr, title in zip(axes, ("sfr10", "sfr50", "sfr_area"), ("SFR10", "SFR50", "SFR area")):
        for orientation, color in (("horizontal", "tab:blue"), ("vertical", "tab:orange")):
            d, v, ok = result.series(orientation, attr)
            _valid_and_invalid(ax, d, v, ok, orientation, color)
        if attr == "sfr10":  # a sampled image holds no higher frequency: an SFR10 above it is aliasing
            ax.axhline(0.5, color="tab:red", linestyle="--", linewidth=0.8, label="Nyquist 0.5 cy/px")
        ax.set_title(title)
        ax.set_xlabel("distance (mm)")
        ax.set_ylabel("cy/px" if attr != "sfr_area" else "")
        ax.grid(alpha=0.3)
        for x, name, style in lines:
            if math.isfinite(x):
                ax.axvline(x, color="gray", linestyle=style, linewidth=1, label=f"{name} {x:.0f} mm")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), frameon=False,
               title="invalid positions: hollow, or x at the bottom where there is no value (reason: the table's notes)")
    fig.suptitle(f"Slanted-edge sharpness over distance: hyperfocal {result.hyperfocal_mm:.0f} mm, "
                 f"best focus {result.best_focus_mm:.0f} mm")
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    return fig


def plot_resolution(result: SharpnessResult, path: Path) -> Path:
    """Angular imagery resolution of the intensity image over distance vs the sensor resolution (Fig. 6-4)."""
    fig = Figure(figsize=(8, 4.5))
    ax = fig.subplots()
    for orientation, sensor, color in (("horizontal", result.sensor_resolution_deg[0], "tab:blue"),
                                       ("vertical", result.sensor_resolution_deg[1], "tab:orange")):
        d, sfr10, ok = result.series(orientation, "sfr10")
        with np.errstate(divide="ignore", invalid="ignore"):
            res = np.where(sfr10 > 0, sensor / sfr10, np.nan)
        _valid_and_invalid(ax, d, res, ok, f"imagery, {orientation}", color)
        ax.axhline(sensor, color=color, linestyle=":", label=f"sensor, {orientation} ({sensor:.3f} deg)")
    ax.set_xlabel("distance (mm)")
    ax.set_ylabel("angular resolution (deg)")
    ax.set_title("Resolution of the intensity image (sensor resolution / SFR10)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return save_png(fig, path, dpi=110)


def shaded_relief(cloud: np.ndarray) -> np.ndarray:
    """Lambert shading (0..1) of an organized cloud from its grid normals, light from the upper left."""
    dx = np.gradient(cloud, axis=1)
    dy = np.gradient(cloud, axis=0)
    normal = np.cross(dx, dy)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    normal *= -np.sign(normal[..., 2:3])  # towards the camera
    light = np.array([-0.5, -0.5, -0.7])
    light /= np.linalg.norm(light)
    return np.clip(normal @ light, 0.0, 1.0)


def face_mask_region(z: np.ndarray) -> np.ndarray:
    """Pixels of the mask and its surroundings: within 150 mm behind the nearest 0.5 % of the points (not the
    wall). The mask may fill only a few % of a small image, so the quantile stays well below that."""
    finite = z[np.isfinite(z)]
    if finite.size == 0:
        raise ValueError("the face mask cloud has no valid point")
    near = np.quantile(finite, 0.005)
    return np.isfinite(z) & (z < near + 150.0)


def face_mask_title(z: np.ndarray, wall_distance_mm: float, step_id: str) -> str:
    """Title naming the depth range the picture shows (the mask's), and the wall distance of the step apart."""
    shown = z[face_mask_region(z)]
    lo, hi = float(np.min(shown)), float(np.max(shown))
    wall = f", wall at {wall_distance_mm:.0f} mm" if math.isfinite(wall_distance_mm) else ""
    return f"Face mask {lo:.0f}-{hi:.0f} mm from the camera (depth shown){wall} ({step_id})"


def plot_face_mask(cloud: np.ndarray, intensity: np.ndarray, wall_distance_mm: float, step_id: str,
                   path: Path) -> Path:
    """The face mask as the camera sees it: shaded relief of the point cloud, depth and intensity (Thesis 2024, 6.7)."""
    z = cloud[..., 2]
    mask = face_mask_region(z)
    rows, cols = np.where(mask)
    crop = (slice(max(rows.min() - 10, 0), rows.max() + 11), slice(max(cols.min() - 10, 0), cols.max() + 11))
    fig = Figure(figsize=(13, 5))
    axes = fig.subplots(1, 3)
    axes[0].imshow(np.where(mask, shaded_relief(cloud), np.nan)[crop], cmap="gray", vmin=0, vmax=1)
    axes[0].set_title("shaded point cloud")
    im = axes[1].imshow(np.where(mask, z, np.nan)[crop], cmap="viridis_r")
    axes[1].set_title("depth z (mm)")
    fig.colorbar(im, ax=axes[1], shrink=0.8)
    axes[2].imshow(intensity[crop], cmap="gray")
    axes[2].set_title("intensity")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(face_mask_title(z, wall_distance_mm, step_id))
    fig.tight_layout()
    return save_png(fig, path, dpi=110)
