"""Forward models for reconcile tests: rewrite a plain simulated run as a camera with an effect would measure it.

The effects are written in the tests from first principles, not with the
effect library's code: a test gives ``rewrite_run`` a function that returns,
for every pixel of one frame, the range error in mm the camera would have
made there (``Pixels`` says what the function may depend on). Every valid
point is moved along its own ray by that error (x, y, z scaled by
(r + dr) / r, r = |(x, y, z)|), so a range error keeps the pixel's direction
as a ToF camera's does; for stereo, a depth error dz at a point is the range
error dz r / z.

The plain run comes from tests/reconcile/runs.py (``simulated_run``). This
module is the physics of the rewritten camera: it imports nothing of the
simulator (tests/test_architecture.py checks).

    run = simulated_run(tmp_path / "plain", "blaze101")
    measured = rewrite_run(run, tmp_path / "measured.h5",
                           lambda px: 2.0 * np.cos(2 * np.pi * px.col / px.width * 3))
"""

from __future__ import annotations

import math
import shutil
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np


@dataclass(frozen=True)
class Pixels:
    """What a range-error function may depend on, for one frame of one step ((H, W) arrays unless noted)."""

    row: np.ndarray  # pixel row index
    col: np.ndarray  # pixel column index
    width: int
    height: int
    x_mm: np.ndarray  # the point as the camera reported it (NaN = invalid)
    y_mm: np.ndarray
    z_mm: np.ndarray
    range_mm: np.ndarray  # |(x, y, z)|
    intensity: np.ndarray
    time_s: float  # device time of the frame
    frame: int  # frame number within the step
    step: dict[str, Any]  # the step's attributes: target, procedure, distance_mm, robot_angle_deg, ...
    fov_deg: tuple[float, float] | None = None  # the camera's (horizontal, vertical) field of view

    @property
    def focal_px(self) -> float:
        """Pinhole focal length in pixels from the horizontal FOV: (W / 2) / tan(FOV_h / 2)."""
        if self.fov_deg is None:
            raise ValueError("the camera's field of view is unknown")
        return (self.width / 2) / math.tan(math.radians(self.fov_deg[0]) / 2)

    def disparity_px(self, baseline_mm: float) -> np.ndarray:
        """Stereo disparity of every point: f b / z (NaN where invalid)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.focal_px * baseline_mm / self.z_mm

    @property
    def radius(self) -> np.ndarray:
        """Distance of the pixel from the image centre over half the image diagonal (0 ... 1)."""
        du, dv = self.col - (self.width - 1) / 2, self.row - (self.height - 1) / 2
        return np.hypot(du, dv) / np.hypot(self.width / 2, self.height / 2)


RangeError = Callable[[Pixels], np.ndarray]


def rewrite_run(source: Path, destination: Path, range_error_mm: RangeError) -> Path:
    """Copy the run at ``source`` to ``destination`` and move every valid point of every frame of every step
    along its ray by ``range_error_mm(pixels)`` mm (a scalar or an (H, W) array). Returns ``destination``."""
    shutil.copyfile(source, destination)
    with h5py.File(destination, "a") as f:
        fov = tuple(float(v) for v in f["camera"].attrs["fov_deg"])
        for group in f["steps"].values():
            x_ds, y_ds, z_ds = group["x"], group["y"], group["z"]
            n, h, w = z_ds.shape
            row, col = np.mgrid[0:h, 0:w]
            times = np.asarray(group["timestamp"][:], float)
            attrs = dict(group.attrs)
            for k in range(n):
                x, y, z = (np.asarray(d[k], float) for d in (x_ds, y_ds, z_ds))
                r = np.sqrt(x * x + y * y + z * z)
                pixels = Pixels(row, col, w, h, x, y, z, r, np.asarray(group["intensity"][k], float),
                                float(times[k]), k, attrs, (fov[0], fov[1]))
                with np.errstate(invalid="ignore", divide="ignore"):
                    factor = (r + np.broadcast_to(range_error_mm(pixels), r.shape)) / r
                for d, v in ((x_ds, x), (y_ds, y), (z_ds, z)):
                    d[k] = (v * factor).astype(np.float32)
    return destination


def stretch_time(source: Path, destination: Path, factor: float) -> Path:
    """Copy the run at ``source`` to ``destination`` with every frame's device time multiplied by ``factor``
    (the same captures spread over a longer run, e.g. to follow a slow warm-up). Returns ``destination``."""
    shutil.copyfile(source, destination)
    with h5py.File(destination, "a") as f:
        for group in f["steps"].values():
            group["timestamp"][:] = group["timestamp"][:] * factor
    return destination


Warp = Callable[[np.ndarray, np.ndarray, int, int], tuple[np.ndarray, np.ndarray]]


def _bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at (u, v) (column, row; pixel centres at integers); NaN outside or where a
    neighbour is NaN."""
    h, w = image.shape
    u0 = np.clip(np.floor(u).astype(int), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, h - 2)
    fu, fv = u - u0, v - v0
    out = ((1 - fu) * (1 - fv) * image[v0, u0] + fu * (1 - fv) * image[v0, u0 + 1]
           + (1 - fu) * fv * image[v0 + 1, u0] + fu * fv * image[v0 + 1, u0 + 1])
    return np.where((u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1), out, np.nan)


def brown_source(k1: float) -> Warp:
    """Brown radial distortion about the image centre, r_d = r_u (1 + k1 (r_u / R)^2), R = half the diagonal:
    the undistorted position (where the plain camera saw the ray) of every distorted pixel, r_u solved by the
    fixed-point iteration r_u = r_d / (1 + k1 (r_u / R)^2)."""
    def where(u: np.ndarray, v: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        cu, cv, big_r = (width - 1) / 2, (height - 1) / 2, math.hypot(width, height) / 2
        r_d = np.hypot(u - cu, v - cv)
        r_u = r_d.copy()
        for _ in range(60):
            r_u = r_d / (1 + k1 * (r_u / big_r) ** 2)
        scale = np.divide(r_u, r_d, out=np.ones_like(r_d), where=r_d > 0)
        return cu + (u - cu) * scale, cv + (v - cv) * scale
    return where


def decentering_source(p1: float, p2: float) -> Warp:
    """Brown-Conrady decentering (tangential) distortion, which no library effect has: with (x, y) from the image
    centre over half the diagonal, x_d = x + 2 p1 x y + p2 (r^2 + 2 x^2), y_d = y + p1 (r^2 + 2 y^2) + 2 p2 x y;
    the undistorted position of every distorted pixel by fixed-point iteration."""
    def where(u: np.ndarray, v: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        cu, cv, big_r = (width - 1) / 2, (height - 1) / 2, math.hypot(width, height) / 2
        xd, yd = (u - cu) / big_r, (v - cv) / big_r
        x, y = xd.copy(), yd.copy()
        for _ in range(60):
            r2 = x * x + y * y
            x, y = (xd - (2 * p1 * x * y + p2 * (r2 + 2 * x * x)),
                    yd - (p1 * (r2 + 2 * y * y) + 2 * p2 * x * y))
        return cu + x * big_r, cv + y * big_r
    return where


def focal_source(fov_deg: tuple[float, float], true_fov_deg: tuple[float, float]) -> Warp:
    """A pinhole of the true FOV where the file says ``fov_deg``: the pixel at u sees the ray of slope
    (u - c) / f_true, which the plain camera (focal f from ``fov_deg``) saw at c + f (u - c) / f_true."""
    def where(u: np.ndarray, v: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        ratio = [math.tan(math.radians(a) / 2) / math.tan(math.radians(b) / 2) for a, b in zip(true_fov_deg, fov_deg)]
        cu, cv = (width - 1) / 2, (height - 1) / 2
        return cu + (u - cu) * ratio[0], cv + (v - cv) * ratio[1]
    return where


def warp_run(source: Path, destination: Path, where: Warp, cloud_corrected: bool) -> Path:
    """Copy the run at ``source`` to ``destination`` as a camera whose pixel (u, v) sees what the plain camera saw
    at ``where(u, v)``: the stack means of the intensity and the cloud are resampled bilinearly, and every pixel
    keeps its own temporal noise (its frames' deviations from its own stack mean are added back), as a camera's
    pixels do whatever its optics; resampling every frame would average the noise of neighbouring pixels (less
    noise, correlated). ``cloud_corrected``: the camera's calibration knows its optics, so every point keeps its
    place (x, y, z resampled); otherwise it turns the range it measures (|p| resampled) into a point along the
    plain pinhole ray of (u, v), slopes ((u - c_u) / f_x, (v - c_v) / f_y) with f from the file's FOV. Returns
    ``destination``."""
    shutil.copyfile(source, destination)
    with h5py.File(destination, "a") as f:
        fov = tuple(float(v) for v in f["camera"].attrs["fov_deg"])
        for group in f["steps"].values():
            n, h, w = group["z"].shape
            v, u = np.mgrid[0:h, 0:w].astype(float)
            su, sv = where(u, v, w, h)
            tx = (u - (w - 1) / 2) / ((w / 2) / math.tan(math.radians(fov[0]) / 2))
            ty = (v - (h - 1) / 2) / ((h / 2) / math.tan(math.radians(fov[1]) / 2))
            intensity = np.asarray(group["intensity"][:], float)
            x, y, z = (np.asarray(group[c][:], float) for c in ("x", "y", "z"))
            r = np.sqrt(x * x + y * y + z * z)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                means = {name: np.nanmean(a, axis=0) for name, a in
                         (("intensity", intensity), ("x", x), ("y", y), ("z", z), ("r", r))}
            warped = {name: _bilinear(m, su, sv) for name, m in means.items()}
            image = warped["intensity"] + (intensity - means["intensity"])
            group["intensity"][:] = np.round(np.nan_to_num(image)).astype(group["intensity"].dtype) \
                if group["intensity"].dtype.kind in "iu" else image
            if cloud_corrected:
                new = [warped[c] + (a - means[c]) for c, a in (("x", x), ("y", y), ("z", z))]
            else:
                measured = warped["r"] + (r - means["r"])
                norm = np.sqrt(1 + tx * tx + ty * ty)
                new = [measured * tx / norm, measured * ty / norm, measured / norm]
            for c, values in zip(("x", "y", "z"), new):
                group[c][:] = values.astype(np.float32)
    return destination


def rewrite_noise(source: Path, destination: Path, change: Callable[[np.ndarray], np.ndarray]) -> Path:
    """Copy the run at ``source`` to ``destination`` with every step's temporal noise rewritten: each valid point
    is its pixel's stack mean plus ``change(deviations)``, where ``deviations`` are the (N, 3, H, W) departures of
    the frames' points from that mean (NaN where invalid). The stack means stay where they were (up to the
    change's own mean). Returns ``destination``."""
    shutil.copyfile(source, destination)
    with h5py.File(destination, "a") as f:
        for group in f["steps"].values():
            points = np.stack([np.asarray(group[c][:], float) for c in ("x", "y", "z")], axis=1)  # (N, 3, H, W)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                mean = np.nanmean(points, axis=0)
            new = mean + change(points - mean)
            for i, c in enumerate(("x", "y", "z")):
                group[c][:] = new[:, i].astype(np.float32)
    return destination


def scale_noise(factor: float) -> Callable[[np.ndarray], np.ndarray]:
    """A camera whose temporal noise is ``factor`` times the plain one's (every deviation scaled)."""
    return lambda deviations: factor * deviations


def box_sum(values: np.ndarray, size: int) -> np.ndarray:
    """Sum of the last two axes' values over a ``size`` x ``size`` window (zero outside the image)."""
    h, w = values.shape[-2:]
    padded = np.zeros(values.shape[:-2] + (h + size, w + size))
    lo = size // 2
    padded[..., lo + 1:lo + 1 + h, lo + 1:lo + 1 + w] = values
    c = padded.cumsum(-1).cumsum(-2)
    return c[..., size:, size:] - c[..., :-size, size:] - c[..., size:, :-size] + c[..., :-size, :-size]


def correlate_noise(size: int) -> Callable[[np.ndarray], np.ndarray]:
    """A camera whose temporal noise is the plain one's made spatially correlated over ``size`` x ``size`` pixels
    with the same per-pixel variance: each frame's deviation is the sum over the window of its valid neighbours'
    deviations divided by the square root of their number (a sum of k independent deviations of equal variance
    has k times the variance)."""
    def change(deviations: np.ndarray) -> np.ndarray:
        ok = np.isfinite(deviations)
        total = box_sum(np.where(ok, deviations, 0.0), size)
        count = box_sum(ok.astype(float), size)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(ok, total / np.sqrt(count), np.nan)
    return change


def correlated_field(shape: tuple[int, int], size: int, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean Gaussian noise of std ``sigma`` correlated over ``size`` x ``size`` pixels: white noise summed
    over the window (drawn beyond the image, so that every window is full) and divided by ``size`` (the sum of
    size^2 unit variances has variance size^2)."""
    h, w = shape
    white = rng.standard_normal((h + size, w + size))
    return sigma * box_sum(white, size)[size // 2:size // 2 + h, size // 2:size // 2 + w] / size
