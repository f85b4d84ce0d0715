"""What a simulated camera should measure on the VDI/VDE 2634-2 ball bar, computed here independently of the
simulator (nothing of it is imported; the camera's numbers come from the model's profile) and of labctl's
evaluation: the exact spheres, each pixel's footprint mean, the profile's noise law.

Per pixel of a sphere, with the pinhole of the profile's FOV:

* footprint mean: the pixel's area sampled at ``FOOTPRINT`` x ``FOOTPRINT`` regular sub-positions, each ray
  cut with the exact sphere; the range (ToF) or depth (stereo) of the hits weighted by the light each returns,
  rho cos^m / t^2 (Lambert, the wall paint's remission and exponent: tests/noise_model.py ``WALL``), and
  reported along the pixel's centre ray (as a camera reports a pixel); the mean is deeper than the sphere at
  the pixel's centre (the front of a sphere is convex towards the camera), so the points lie slightly inside;
* noise: ToF, the shot-noise law of tests/noise_model.py along the ray with that light relative to the
  90 % wall at 2 m on the axis (``tof_sigma_mm``); stereo: disparity noise s (1 + g theta^2 / (pi/2 - theta)^2)
  with s from ``noise_mm_at_2m``, rounded to the disparity step; then the output rounded to ``output_step_mm``;
* the rim rule, in its definition (pixel ray at most 60 deg incidence on the true sphere and one pixel
  inside its silhouette), and a least-squares sphere of its own;
* a measurement: per pixel the mean of the frames it averages (``frames_per_measurement`` of the run's steps,
  all of a step's frames when it does not say), each frame drawn independently.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from tests.noise_model import REFERENCE_MM, WALL, focal_baseline, tof_sigma_mm

FOOTPRINT = 8


def ball_bar_centres(wall_distance_mm: float, params: dict) -> list[np.ndarray]:
    """The two sphere centres: the bar's middle ``gap_mm`` in front of the wall, ``offset_mm`` (camera frame: x
    right, y down; none: on the axis) off the axis, along its direction."""
    phi, tilt = math.radians(params["orientation_deg"]), math.radians(params["tilt_deg"])
    axis = np.array([math.cos(phi) * math.cos(tilt), math.sin(phi) * math.cos(tilt), math.sin(tilt)])
    x_mm, y_mm = params.get("offset_mm", (0.0, 0.0))
    middle = np.array([x_mm, y_mm, wall_distance_mm - params["gap_mm"]])
    return [middle - axis * params["spacing_mm"] / 2, middle + axis * params["spacing_mm"] / 2]


def _rays(profile, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3) rays (x/z, y/z, 1) at pixel positions u, v of the profile's pinhole."""
    fx = profile.width / 2 / math.tan(math.radians(profile.fov_h_deg) / 2)
    fy = profile.height / 2 / math.tan(math.radians(profile.fov_v_deg) / 2)
    return np.stack([(u - (profile.width - 1) / 2) / fx, (v - (profile.height - 1) / 2) / fy, np.ones_like(u)], -1)


def _cut(rays: np.ndarray, centre: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Range along the unit rays to the sphere's front (NaN where missed) and the incidence cosine there."""
    unit = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    b = unit @ centre
    disc = b**2 - (centre @ centre - radius**2)
    with np.errstate(invalid="ignore"):
        t = np.where(disc >= 0, b - np.sqrt(disc), np.nan)
    normal = (unit * t[..., None] - centre) / radius
    return t, np.clip(-(normal * unit).sum(-1), 0.0, 1.0)


@dataclass(frozen=True)
class SpherePixels:
    """The pixels of one sphere that the rim rule keeps, with what the model says they report."""

    rows: np.ndarray
    cols: np.ndarray
    rays: np.ndarray  # (n, 3) centre rays (x/z, y/z, 1)
    mean_range: np.ndarray  # light-weighted footprint mean of the range (ToF) or depth (stereo), mm
    sigma: np.ndarray  # range noise (ToF, mm) or disparity noise (stereo, px)


def sphere_pixels(model, centre: np.ndarray, radius: float, max_incidence_deg: float = 60.0,
                  margin_px: float = 1.0) -> SpherePixels:
    p = model.profile()
    v, u = np.mgrid[0:p.height, 0:p.width].astype(float)
    rays = _rays(p, u, v)
    unit = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    distance = float(np.linalg.norm(centre))
    gamma = np.arccos(np.clip(unit @ centre / distance, -1, 1))
    pixel_rad = math.atan(1 / (p.width / 2 / math.tan(math.radians(p.fov_h_deg) / 2)))
    keep = (gamma <= math.asin(radius / distance) - margin_px * pixel_rad) & (
        distance * np.sin(gamma) <= radius * math.sin(math.radians(max_incidence_deg)))
    rows, cols = np.nonzero(keep)
    offsets = (np.arange(FOOTPRINT) + 0.5) / FOOTPRINT - 0.5
    du, dv = (a.ravel() for a in np.meshgrid(offsets, offsets))
    sub = _rays(p, cols[:, None] + du, rows[:, None] + dv)
    t, cos = _cut(sub, centre, radius)
    light = _relative_light(cos, t)
    norm = np.linalg.norm(sub, axis=-1)
    along = t if p.technology == "tof" else t / norm  # range, or depth z = t / |(x/z, y/z, 1)|
    mean = (light * along).sum(1) / light.sum(1)
    if p.technology == "tof":
        sigma = tof_sigma_mm(p, light.mean(1))
    else:
        theta = np.arccos((light * cos).sum(1) / light.sum(1))
        s = p.noise_mm_at_2m * focal_baseline(p) / REFERENCE_MM**2
        sigma = s * (1 + p.angle_noise_gain * theta**2 / np.maximum(math.pi / 2 - theta, 1e-3) ** 2)
    return SpherePixels(rows, cols, rays[rows, cols], mean, sigma)


def _relative_light(cos: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Light the wall paint returns at incidence cosine ``cos`` and range ``t`` (mm), relative to the 90 % wall
    at 2 m on the axis: (rho / 0.9) cos^m (2000 / t)^2."""
    rho, m = WALL
    return rho / 0.9 * cos**m * (REFERENCE_MM / t) ** 2


def draw_points(model, pixels: SpherePixels, valid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One frame's points of the sphere's valid kept pixels, with the model's noise and output rounding."""
    p = model.profile()
    keep = valid[pixels.rows, pixels.cols]
    rays, mean, sigma = pixels.rays[keep], pixels.mean_range[keep], pixels.sigma[keep]
    noise = rng.standard_normal(len(mean))
    if p.technology == "tof":
        z = (mean + sigma * noise) / np.linalg.norm(rays, axis=1)
    else:
        fb = focal_baseline(p)
        disparity = fb / mean + sigma * noise
        if p.disparity_step_px > 0:
            disparity = np.round(disparity / p.disparity_step_px) * p.disparity_step_px
        z = fb / disparity
    points = rays * z[:, None]
    step = model.effect_params()["quantization"].step_mm if "quantization" in model.effect_params() else 0.0
    return np.round(points / step) * step if step > 0 else points


def mean_points(model, pixels: SpherePixels, valids: list[np.ndarray], rng: np.random.Generator) -> np.ndarray:
    """One measurement averaging the frames of ``valids`` (each frame's valid pixels): every frame drawn as in
    ``draw_points``, each kept pixel the mean of the frames in which it is valid."""
    total, count = np.zeros((len(pixels.rows), 3)), np.zeros(len(pixels.rows))
    for valid in valids:
        keep = valid[pixels.rows, pixels.cols]
        total[keep] += draw_points(model, pixels, valid, rng)
        count[keep] += 1
    seen = count > 0
    return total[seen] / count[seen][:, None]


def sphere_fit(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Least-squares sphere (geometric distances): centre, radius, radial deviations."""
    centre0 = points.mean(axis=0) + np.array([0.0, 0.0, 10.0])

    def residuals(q: np.ndarray) -> np.ndarray:
        return np.linalg.norm(points - q[:3], axis=1) - q[3]

    q = optimize.least_squares(residuals, np.append(centre0, 20.0)).x
    return q[:3], float(q[3]), residuals(q)


def plate_model(model, distance_mm: float, tilt_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat plate ``distance_mm`` away on the axis, turned ``tilt_deg`` about the vertical, at every pixel (its
    extent aside): (H, W, 3) noise-free points, (H, W, 3) the direction one unit of noise moves a point, (H, W)
    that noise: ToF ``tof_sigma_mm`` along the unit ray with the light the plate returns; stereo z^2 / (f B) times the
    disparity noise with its angle term (and the disparity step's step^2 / 12) along (x/z, y/z, 1)."""
    p = model.profile()
    v, u = np.mgrid[0:p.height, 0:p.width].astype(float)
    rays = _rays(p, u, v)
    unit = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    tilt = math.radians(tilt_deg)
    normal = np.array([-math.sin(tilt), 0.0, math.cos(tilt)])
    cos = np.abs(unit @ normal)
    t = distance_mm * normal[2] / cos
    if p.technology == "tof":
        return unit * t[..., None], unit, tof_sigma_mm(p, _relative_light(cos, t))
    theta = np.arccos(cos)
    s = p.noise_mm_at_2m * focal_baseline(p) / REFERENCE_MM**2
    disparity = s * (1 + p.angle_noise_gain * theta**2 / (math.pi / 2 - theta) ** 2)
    z = t * unit[..., 2]
    return unit * t[..., None], rays, z**2 / focal_baseline(p) * np.sqrt(disparity**2 + p.disparity_step_px**2 / 12)


def plate_flatness(model, points: np.ndarray, along: np.ndarray, sigma: np.ndarray, rng: np.random.Generator) -> float:
    """F of one frame of the plate's pixels: the noise drawn, the output rounded, the range of the deviations from
    the orthogonal least-squares plane after the 0.3 % rule."""
    return plane_range(_plate_frame(model, points, along, sigma, rng))


def mean_plate_flatness(model, plate: tuple[np.ndarray, np.ndarray, np.ndarray], masks: list[np.ndarray],
                        rng: np.random.Generator) -> float:
    """F of one measurement averaging the frames of ``masks`` (each frame's plate pixels): every frame drawn as in
    ``plate_flatness``, each pixel the mean of the frames that saw it."""
    total, count = np.zeros(plate[0].shape), np.zeros(plate[0].shape[:-1])
    for mask in masks:
        total[mask] += _plate_frame(model, *(a[mask] for a in plate), rng)
        count[mask] += 1
    seen = count > 0
    return plane_range(total[seen] / count[seen][:, None])


def _plate_frame(model, points: np.ndarray, along: np.ndarray, sigma: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One frame of the plate's pixels: the noise drawn, the output rounded."""
    noisy = points + along * (sigma * rng.standard_normal(sigma.size))[:, None]
    step = model.effect_params()["quantization"].step_mm if "quantization" in model.effect_params() else 0.0
    return np.round(noisy / step) * step if step > 0 else noisy


def plane_range(points: np.ndarray) -> float:
    """Range of the deviations from the orthogonal least-squares plane after the 0.3 % rule."""
    centred = points - points.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][2]
    return rule_range(centred @ normal)


def rule_range(deviations: np.ndarray) -> float:
    """Range after the 0.3 % rule (at most floor(0.003 n) points beyond 3 RMS, largest first, left out)."""
    rms = np.sqrt(np.mean(deviations**2))
    order = np.argsort(-np.abs(deviations))
    beyond = order[np.abs(deviations[order]) > 3 * rms][: int(0.003 * deviations.size)]
    kept = np.delete(deviations, beyond)
    return float(kept.max() - kept.min())


def wall_mm(step) -> float:
    """The camera-wall distance: the laser's reference where the run has one, else the stage's."""
    reference = float(step.attrs.get("reference_distance_mm", math.nan))
    return reference if math.isfinite(reference) else float(step.attrs["distance_mm"])


def _measurements(step, masks: list[np.ndarray], per: int | None) -> list[list[np.ndarray]]:
    """The frames' masks grouped into measurements of ``per`` consecutive frames (None: the step's
    ``frames_per_measurement``, all of its frames when the run does not say), a last incomplete group left out."""
    if per is None:
        per = min(json.loads(step.attrs["target_json"]).get("frames_per_measurement", len(masks)), len(masks))
    return [masks[i:i + per] for i in range(0, len(masks) - per + 1, per)]


def predicted_acceptance(model, reader, rng: np.random.Generator, n_draws: int,
                         frames_per_measurement: int | None = None) -> list[dict[str, list[float]]]:
    """``n_draws`` repetitions of every ball-bar and plate measurement of the run, from tests/artefact_model
    (the exact spheres and plates above, each frame's valid pixels as the run has them, each measurement the
    per-pixel mean of ``frames_per_measurement`` frames, None: as the run's steps say): per draw, each
    quantity's measurements."""
    bars = []
    for step in reader.steps("sphere_bar"):
        params = json.loads(step.attrs["target_json"])
        radius = params["diameter_mm"] / 2
        pixels = [sphere_pixels(model, c, radius) for c in ball_bar_centres(wall_mm(step), params)]
        valids = [np.isfinite(step.frame("z", k)) for k in range(step.group["z"].shape[0])]
        bars.append((params, pixels, _measurements(step, valids, frames_per_measurement)))
    plates = []
    for step in reader.steps("flatness"):
        params = json.loads(step.attrs["target_json"])
        wall = wall_mm(step)
        plate = plate_model(model, wall - params["gap_mm"], params["tilt_deg"])
        masks = [np.isfinite(z) & (z < wall - params["gap_mm"] / 2)
                 for z in (step.frame("z", k) for k in range(step.group["z"].shape[0]))]
        plates.append((plate, _measurements(step, masks, frames_per_measurement)))
    draws = []
    for _ in range(n_draws):
        values: dict[str, list[float]] = {name: [] for name in ("probing_error_form_mm", "probing_error_size_mm",
                                                                  "sphere_spacing_error_mm", "flatness_error_mm")}
        for params, pixels, measurements in bars:
            for valids in measurements:
                fits = [sphere_fit(mean_points(model, p, valids, rng)) for p in pixels]
                values["probing_error_form_mm"].append(max(float(np.ptp(f[2])) for f in fits))
                values["probing_error_size_mm"].append(max((2 * f[1] - params["diameter_mm"] for f in fits), key=abs))
                values["sphere_spacing_error_mm"].append(
                    float(np.linalg.norm(fits[0][0] - fits[1][0])) - params["spacing_mm"])
        for plate, measurements in plates:
            values["flatness_error_mm"].extend(mean_plate_flatness(model, plate, masks, rng) for masks in measurements)
        draws.append(values)
    return draws
