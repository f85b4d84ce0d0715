"""Areal surface texture of a flat target (Thesis 2024, 4.2.2).

* primary surface: stack-mean depth minus the form, the least-squares plane
  z = a + b x + c y (ISO 25178-2 F-operation), so a residual tilt is not texture;
* waviness: the primary surface low-pass filtered with the ISO 16610-61 areal
  Gaussian filter, weighting s(x) = exp(-pi (x / (alpha lambda_c))^2),
  alpha = sqrt(ln 2 / pi), 50 % transmission at the cut-off lambda_c; as a
  Gaussian this is sigma = alpha lambda_c / sqrt(2 pi) = 0.18739 lambda_c;
* roughness: primary minus waviness;
* Sq (ISO 25178-2 eq. 4-1 of Thesis 2024): root mean square about the mean.

lambda_c is given in millimetres and converted to pixels per axis with the
measured lateral pixel size (median spacing of neighbouring points). Invalid
pixels are filled by normalized convolution before filtering (not zeros) and
excluded from Sq; a lambda_c / 2 border is cropped because the filter is
biased there.

The Type A uncertainty of the three Sq (:func:`sq_jackknife`) is the delete-a-group jackknife over the stack's
frames (Efron & Tibshirani 1993, 11.2; Busing et al. 1999 for groups): Sq evaluated again on the stack-mean
depth without each group of frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from metrics.uncertainty import delete_a_group_jackknife

GAUSS_ALPHA = math.sqrt(math.log(2.0) / math.pi)
SIGMA_PER_CUTOFF = GAUSS_ALPHA / math.sqrt(2.0 * math.pi)  # 0.18739


def gaussian_transmission(wavelength: float, cutoff: float) -> float:
    """Amplitude transmission of the ISO 16610-61 Gaussian low-pass at ``wavelength``.

    Examples
    --------
    50 % at the cut-off wavelength, 2^-25 (nothing) at a fifth of it.

    >>> round(gaussian_transmission(25.0, 25.0), 6), round(gaussian_transmission(5.0, 25.0), 6)
    (0.5, 0.0)
    """
    return math.exp(-math.pi * (GAUSS_ALPHA * cutoff / wavelength) ** 2)


def lateral_pixel_size_mm(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Median spacing of horizontally (x) and vertically (y) neighbouring valid points.

    Examples
    --------
    >>> y, x = np.mgrid[0:4, 0:5] * np.array([[[3.0]], [[2.0]]])  # 2 mm columns, 3 mm rows
    >>> lateral_pixel_size_mm(x, y)
    (2.0, 3.0)
    """
    dx = np.abs(np.diff(x, axis=1))
    dy = np.abs(np.diff(y, axis=0))
    sx, sy = dx[np.isfinite(dx)], dy[np.isfinite(dy)]
    if not sx.size or not sy.size:
        raise ValueError("too few valid neighbouring points to measure the pixel size")
    return float(np.median(sx)), float(np.median(sy))


def fit_plane(x: np.ndarray, y: np.ndarray, z: np.ndarray, valid: np.ndarray) -> tuple[float, float, float]:
    """Least-squares plane z = a + b x + c y over valid points; returns (a, b, c).

    Examples
    --------
    >>> y, x = np.mgrid[0:5, 0:6].astype(float)
    >>> a, b, c = fit_plane(x, y, 5.0 + 0.1 * x - 0.2 * y, np.ones(x.shape, bool))
    >>> round(a, 6), round(b, 6), round(c, 6)
    (5.0, 0.1, -0.2)
    """
    xs, ys, zs = x[valid], y[valid], z[valid]
    if zs.size < 3:
        raise ValueError("fewer than 3 valid points: cannot fit the form plane")
    x0, y0 = xs.mean(), ys.mean()
    design = np.column_stack([np.ones_like(xs), xs - x0, ys - y0])
    (a, b, c), *_ = np.linalg.lstsq(design, zs, rcond=None)
    return float(a - b * x0 - c * y0), float(b), float(c)


def normalized_gaussian(values: np.ndarray, valid: np.ndarray, sigma_yx: tuple[float, float]) -> np.ndarray:
    """Gaussian low-pass of ``values`` where only ``valid`` samples carry weight (normalized convolution).

    Result = G * (v w) / G * w with w the validity mask; undefined (NaN) only
    where no valid sample lies within reach of the kernel.

    Examples
    --------
    A constant surface stays constant, also where invalid samples (here a hole of garbage) are bridged.

    >>> values, valid = np.full((7, 7), 7.0), np.ones((7, 7), bool)
    >>> values[3, 3], valid[3, 3] = 1e6, False
    >>> bool(np.allclose(normalized_gaussian(values, valid, (1.0, 1.0)), 7.0))
    True
    """
    weight = valid.astype(np.float64)
    data = np.where(valid, values, 0.0)
    num = ndimage.gaussian_filter(data, sigma_yx, mode="constant", cval=0.0)
    den = ndimage.gaussian_filter(weight, sigma_yx, mode="constant", cval=0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 1e-6, num / den, np.nan)


def rms_about_mean(values: np.ndarray) -> float:
    """Sq: sqrt(mean((v - mean v)^2)) over finite values.

    Examples
    --------
    >>> rms_about_mean(np.array([1.0, 3.0, np.nan]))  # deviations -1, +1 from the mean 2
    1.0
    """
    v = values[np.isfinite(values)]
    return float(np.sqrt(np.mean((v - v.mean()) ** 2))) if v.size else float("nan")


@dataclass(frozen=True)
class SurfaceTexture:
    primary: np.ndarray
    waviness: np.ndarray
    roughness: np.ndarray
    sq_primary_mm: float
    sq_waviness_mm: float
    sq_roughness_mm: float
    cutoff_mm: float
    cutoff_px: tuple[float, float]
    crop_px: tuple[int, int]


def surface_texture(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, valid: np.ndarray, cutoff_mm: float = 25.0
) -> SurfaceTexture:
    """Primary, waviness and roughness surfaces and their Sq (Thesis 2024, 4.2.2).

    ``x``, ``y``, ``z`` are stack-mean maps (mm); the returned maps are NaN
    outside the valid, cropped evaluation area.

    Examples
    --------
    A tilted plane (the form, removed) carrying a +-0.5 mm checker texture of 2 mm period, far
    below the 25 mm cut-off: all of it is roughness, Sq = 0.5 mm; the waviness is flat.

    >>> y, x = np.mgrid[0:60, 0:60].astype(float)  # 1 mm pixels
    >>> z = 1000.0 + 0.05 * x + 0.5 * (-1.0) ** (x + y)
    >>> texture = surface_texture(x, y, z, np.ones(z.shape, bool))
    >>> round(texture.sq_primary_mm, 3), round(texture.sq_waviness_mm, 3), round(texture.sq_roughness_mm, 3)
    (0.5, 0.0, 0.5)
    """
    valid = valid & np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    a, b, c = fit_plane(x, y, z, valid)
    primary = np.where(valid, z - (a + b * x + c * y), np.nan)
    px, py = lateral_pixel_size_mm(np.where(valid, x, np.nan), np.where(valid, y, np.nan))
    cutoff_px = (cutoff_mm / px, cutoff_mm / py)
    sigma_yx = (SIGMA_PER_CUTOFF * cutoff_px[1], SIGMA_PER_CUTOFF * cutoff_px[0])
    waviness = normalized_gaussian(primary, valid, sigma_yx)
    roughness = primary - waviness
    crop_x, crop_y = math.ceil(cutoff_px[0] / 2), math.ceil(cutoff_px[1] / 2)
    h, w = z.shape
    if 2 * crop_x >= w or 2 * crop_y >= h:
        raise ValueError(
            f"cut-off {cutoff_mm:g} mm = {cutoff_px[0]:.0f} x {cutoff_px[1]:.0f} px leaves nothing after "
            f"cropping a {w} x {h} px image"
        )
    keep = np.zeros_like(valid)
    keep[crop_y : h - crop_y, crop_x : w - crop_x] = True
    keep &= valid

    def masked(m: np.ndarray) -> np.ndarray:
        return np.where(keep, m, np.nan)

    primary, waviness, roughness = masked(primary), masked(waviness), masked(roughness)
    return SurfaceTexture(
        primary=primary,
        waviness=waviness,
        roughness=roughness,
        sq_primary_mm=rms_about_mean(primary),
        sq_waviness_mm=rms_about_mean(waviness),
        sq_roughness_mm=rms_about_mean(roughness),
        cutoff_mm=cutoff_mm,
        cutoff_px=cutoff_px,
        crop_px=(crop_x, crop_y),
    )


def sq_jackknife(x: np.ndarray, y: np.ndarray, z_replicates: np.ndarray, valid: np.ndarray,
                 cutoff_mm: float = 25.0) -> tuple[float, float, float]:
    """Type A standard uncertainties (GUM 4.2) of Sq of the primary, waviness and roughness surface: the
    delete-a-group jackknife (``metrics.uncertainty.delete_a_group_jackknife``) of :func:`surface_texture` over
    the (G, H, W) ``z_replicates``, the stack-mean depth without each of G groups of frames
    (``metrics.stack.leave_group_out_means``), on the stack-mean ``x`` and ``y`` and the pixels ``valid`` in the
    full stack and finite in the replicate. x and y enter Sq only through the form plane's coordinates and the
    pixel size that scales the cut-off, so their noise, far below a pixel, is left out. A replicate that cannot
    be evaluated is left out; NaN where fewer than two remain.

    Where Sq is all noise (a flat wall seen by a camera without texture of its own) the jackknife states more
    than Sq's spread over repeated stacks: Sq^2 is then quadratic in the noise of the mean, and the jackknife's
    linear approximation of it has twice its variance (the jackknife variance errs on the large side, Efron &
    Stein 1981); on simulated flat walls u was 1.5 to 1.7 times the spread. Where a texture of the camera's
    own dominates, Sq is near linear in the noise and the jackknife states its spread (with a fixed per-pixel
    pattern of 0.5 mm on the simulated wall, u was 0.89 to 1.02 times the spread).

    Examples
    --------
    Three replicates of a +-a checker texture far below the cut-off with a = 0.4, 0.5 and 0.6 mm: Sq primary and
    roughness are a, so their jackknife is sqrt(2 / 3 sum (a - 0.5)^2) = 0.1155; the waviness is flat.

    >>> y, x = np.mgrid[0:60, 0:60].astype(float)  # 1 mm pixels
    >>> checker = (-1.0) ** (x + y)
    >>> z = 1000.0 + np.array([0.4, 0.5, 0.6])[:, None, None] * checker
    >>> [round(u, 4) for u in sq_jackknife(x, y, z, np.ones(x.shape, bool))]
    [0.1155, 0.0, 0.1155]
    """
    rows = []
    for z in z_replicates:
        try:
            texture = surface_texture(x, y, z, valid & np.isfinite(z), cutoff_mm)
            rows.append((texture.sq_primary_mm, texture.sq_waviness_mm, texture.sq_roughness_mm))
        except ValueError:
            rows.append((math.nan,) * 3)
    primary, waviness, roughness = delete_a_group_jackknife(np.array(rows))
    return primary, waviness, roughness
