"""One simulated frame of a scene, and figures of it for people to judge."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from sim.effects import plate_placement_mm
from sim.geometry import Pose
from sim.model import SimModel
from sim.scenes.targets import PLATE_MATERIALS, build_scene, plate_scene
from sim.stereo import StereoSensor
from sim.tof import ToFSensor

#: where each target is shown by default: camera-wall distance (stage) or robot angle
GALLERY: dict[str, dict[str, Any]] = {
    "wall": {"distance_mm": 2000.0},
    "slanted_edge": {"distance_mm": 1000.0},
    "checkerboard": {"distance_mm": 800.0},
    "boehler_star": {"distance_mm": 1300.0, "params": {"segments": 72, "gap_mm": 300.0}},
    "face_mask": {"distance_mm": 1100.0, "params": {"gap_mm": 300.0}},
    "silicone": {"angle_deg": 30.0},
}


def simulate_frame(model: SimModel, target: str, params: Mapping[str, Any] | None = None,
                   distance_mm: float = 1000.0, angle_deg: float = 0.0, radius_mm: float = 850.0,
                   projector: bool = True, seed: int = 0) -> tuple[np.ndarray, ...]:
    """(x, y, z, intensity, confidence) of one frame of ``target`` seen by ``model``'s camera."""
    profile, effects = model.profile(), model.effect_params()
    params = dict(params or {})
    if target in PLATE_MATERIALS:
        axis_mm, plate_mm = plate_placement_mm(effects)
        pose = Pose.on_circle(angle_deg, radius_mm, axis_mm)
        scene = plate_scene(target, profile.wavelength_nm, offset_mm=plate_mm, **params)
    else:
        pose = Pose.at_origin(model.lab.tilt_x_deg, model.lab.tilt_y_deg)
        scene = build_scene(target, params, profile.wavelength_nm, distance_mm)
    if profile.technology == "tof":
        sensor = ToFSensor(profile, effects)
        prepared = sensor.prepare(scene, pose, profile.exposure_us, seed, 0)
    else:
        stereo = StereoSensor(profile, effects)
        prepared = stereo.prepare(scene, pose, profile.exposure_us, seed, 0, projector=projector)
        sensor = stereo
    return sensor.frame(prepared, 0, 0.0)


def _show(ax: Any, image: np.ndarray, title: str, cmap: str) -> None:
    finite = image[np.isfinite(image)]
    lo, hi = (np.quantile(finite, [0.01, 0.99]) if finite.size else (0.0, 1.0))
    masked = np.ma.masked_invalid(image)
    colormap = matplotlib.colormaps[cmap].with_extremes(bad="white")
    im = ax.imshow(masked, cmap=colormap, vmin=lo, vmax=hi if hi > lo else lo + 1, interpolation="nearest")
    ax.set_title(title, fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.figure.colorbar(im, ax=ax, shrink=0.7)


def preview_figure(model: SimModel, targets: list[tuple[str, dict[str, Any]]], path: Path) -> Path:
    """A grid: per target one column, intensity above depth (invalid pixels white)."""
    profile = model.profile()
    fig = Figure(figsize=(3.6 * len(targets), 5.6))
    axes = fig.subplots(2, len(targets), squeeze=False)
    for col, (target, where) in enumerate(targets):
        frame = simulate_frame(model, target, where.get("params"), where.get("distance_mm", 1000.0),
                               where.get("angle_deg", 0.0), projector=where.get("projector", True))
        place = f"{where['distance_mm']:.0f} mm" if "distance_mm" in where else f"{where.get('angle_deg', 0):g} deg"
        _show(axes[0, col], frame[3], f"{target} @ {place}: intensity", "gray")
        _show(axes[1, col], frame[2], "z (mm), white = invalid", "viridis")
    fig.suptitle(f"{profile.vendor} {profile.model} (simulated, {profile.width} x {profile.height})")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    return path
