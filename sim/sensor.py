"""What ToF and stereo sensors share: true optics, reported rays, optical blur.

* True optics: pinhole of the true FOV (the effects' ``true_fov_deg``, else
  the datasheet's) with Brown radial distortion (their ``lens_distortion``)
  decide which ray each pixel sees.
* Reported rays: the camera turns a range or depth into x, y, z with its own
  calibration, the true FOV; it corrects the distortion in the cloud unless
  the distortion is carried into the cloud. Their slopes x/z, y/z are kept as a
  (1, W) row and an (H, 1) column, or (H, W) maps when a corrected distortion
  makes them non-separable.
* Optical blur: the in-focus lens PSF (a Gaussian of the profile's
  ``lens_sigma_px``) and, with an effect's ``blur_px`` (sim/effects/defocus.py),
  a uniform disc of diameter b(s), applied in the Fourier domain with their exact OTFs
  exp(-2 pi^2 sigma^2 f^2) and 2 J1(pi b f) / (pi b f) (edges reflected), on
  2 x 2 sub-pixels before each pixel integrates its four: the image's SFR is
  then |sinc f| x lens OTF x defocus OTF also above Nyquist (``edge_sfr``).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import fft as sfft
from scipy import optimize, special

from metrics.optics import Pinhole
from sim.effects import EffectParams, acting
from sim.optics import CameraOptics
from sim.profiles import CameraProfile

#: SFR area lost at the hyperfocal distance by the default circle of confusion (Thesis 2024, 5.1.2's 90 % plateau rule)
HYPERFOCAL_SFR_AREA_RATIO = 0.9


def disc_otf(freq: np.ndarray, diameter_px: float) -> np.ndarray:
    """OTF of a uniform disc of ``diameter_px``: 2 J1(pi b f) / (pi b f)."""
    x = np.pi * diameter_px * np.asarray(freq, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(x > 1e-8, 2.0 * special.j1(x) / np.where(x > 1e-8, x, 1.0), 1.0)


def gaussian_otf(freq: np.ndarray, sigma_px: float) -> np.ndarray:
    """OTF of a Gaussian PSF: exp(-2 pi^2 sigma^2 f^2)."""
    return np.exp(-2.0 * math.pi**2 * sigma_px**2 * np.asarray(freq, float) ** 2)


def edge_sfr(freq: np.ndarray, lens_sigma_px: float, disc_px: float = 0.0) -> np.ndarray:
    """Expected edge SFR of the camera: |sinc f| (pixel) x lens OTF x |defocus OTF|."""
    return np.abs(np.sinc(freq)) * gaussian_otf(freq, lens_sigma_px) * np.abs(disc_otf(freq, disc_px))


@lru_cache(maxsize=64)
def default_coc_px(lens_sigma_px: float) -> float:
    """Disc diameter whose blur leaves ``HYPERFOCAL_SFR_AREA_RATIO`` of the in-focus SFR area (0..1 cy/px)."""
    freq = np.linspace(0.0, 1.0, 2001)
    focused = np.trapezoid(edge_sfr(freq, lens_sigma_px), freq)

    def loss(b: float) -> float:
        return np.trapezoid(edge_sfr(freq, lens_sigma_px, b), freq) / focused - HYPERFOCAL_SFR_AREA_RATIO

    return float(optimize.brentq(loss, 1e-3, 20.0))


def blur_diameter_px(effects: dict[str, EffectParams], distance_mm: float, lens_sigma_px: float) -> float:
    """Diameter of the blur disc at ``distance_mm`` of a lens with in-focus PSF ``lens_sigma_px`` (the widest of the
    effects' ``blur_px``; 0 without)."""
    blurs = acting(effects, "blur_px")
    if not blurs:
        return 0.0
    coc = default_coc_px(lens_sigma_px)
    return max(hook(distance_mm, params, coc) for hook, params in blurs)


def _filter(field: np.ndarray, sigma_px: float, disc_px: float) -> np.ndarray:
    """Gaussian and disc OTFs applied in the Fourier domain; edges reflected, padded to a fast FFT size."""
    pad = int(math.ceil(4 * sigma_px + disc_px)) + 2
    padded = np.pad(field, pad, mode="reflect")
    real = not np.iscomplexobj(field)
    shape = tuple(sfft.next_fast_len(n, real=real) for n in padded.shape)
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = (np.fft.rfftfreq if real else np.fft.fftfreq)(shape[1])[None, :]
    freq = np.hypot(fx, fy)
    otf = gaussian_otf(freq, sigma_px)
    if disc_px > 0:  # a disc of no size passes every frequency (its OTF is 1)
        otf = otf * disc_otf(freq, disc_px)
    if real:
        out = sfft.irfft2(sfft.rfft2(padded, shape, workers=-1) * otf, shape, workers=-1)
    else:
        out = sfft.ifft2(sfft.fft2(padded, shape, workers=-1) * otf, workers=-1)
    return out[pad : pad + field.shape[0], pad : pad + field.shape[1]]


def _distortion(effects: dict[str, EffectParams]) -> tuple[float, bool]:
    """The effects' lens distortion k1 (0: none) and whether the reported cloud follows the distorted rays."""
    k1, in_cloud = 0.0, True
    for hook, params in acting(effects, "lens_distortion"):
        k1, in_cloud = hook(params)
    return k1, in_cloud


def camera_optics(profile: CameraProfile, effects: dict[str, EffectParams]) -> CameraOptics:
    """The true optics of a camera under its model's effects: its true field of view and lens distortion."""
    fov: tuple[float, float] = (profile.fov_h_deg, profile.fov_v_deg)
    for hook, params in acting(effects, "true_fov_deg"):
        fov = hook(params)
    return CameraOptics(Pinhole(profile.width, profile.height, *fov), _distortion(effects)[0])


class SensorOptics:
    """True and reported geometry of a camera under its model's effects, and its blur."""

    def __init__(self, profile: CameraProfile, effects: dict[str, EffectParams]) -> None:
        self.profile = profile
        self.effects = effects
        self.optics = camera_optics(profile, effects)
        k1, in_cloud = _distortion(effects)
        pin = self.optics.pinhole
        if k1 != 0.0 and not in_cloud:
            u, v = self.optics.undistort(*self.optics.pixel_grid())
            self.tx = ((u - pin.cx) / pin.fx).astype(np.float32)
            self.ty = ((v - pin.cy) / pin.fy).astype(np.float32)
        else:  # separable: one (1, W) row and one (H, 1) column
            tx, ty = pin.slopes
            self.tx, self.ty = tx.astype(np.float32), ty.astype(np.float32)
        self.cos_alpha = self.optics.directions(*self.optics.pixel_grid())[2]

    def blur_diameter_px(self, distance_mm: float) -> float:
        """Defocus disc at ``distance_mm`` (``blur_diameter_px``)."""
        return blur_diameter_px(self.effects, distance_mm, self.profile.lens_sigma_px)

    def blur(self, field: np.ndarray, distance_mm: float, oversample: int = 1) -> np.ndarray:
        """Lens PSF (and defocus disc) applied to a real or complex field, then integrated over each pixel.

        ``field`` holds ``oversample`` x ``oversample`` samples per pixel
        ((H k, W k), e.g. ``Rendered.irradiance_fine``): the blur acts on that
        grid, before the pixel integrates (the k x k mean), so detail above the
        pixel's Nyquist frequency is blurred as the lens does it, not folded
        back first. Returns (H, W).
        """
        k = oversample
        sigma, disc = self.profile.lens_sigma_px * k, self.blur_diameter_px(distance_mm) * k
        out = field
        if sigma > 0 or disc > 0:
            out = _filter(field, sigma, disc)
        if k > 1:
            h, w = out.shape[0] // k, out.shape[1] // k
            out = out.reshape(h, k, w, k).mean(axis=(1, 3))
        return out
