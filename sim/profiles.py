"""Built-in camera profiles: blaze101, amt100, flexx2, d455.

Every number carries its source in ``SOURCES``: Thesis 2024's Table 6-1
(datasheet values collected there), its text, a datasheet, or ``assumption``
when no public number exists (those are the knobs the reconcile workflow is
meant to correct from measurements).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

T61 = "Thesis 2024, Table 6-1 (manufacturer datasheets)"
#: largest sensor side a model may give (px): beyond every camera the simulator stands for
MAX_SENSOR_PX = 8192


@dataclass(frozen=True)
class CameraProfile:
    """Physical description of one camera model, used by the simulator.

    ``noise_mm_at_2m`` is the temporal depth noise (1 sigma) of the centre
    pixel on the 90 % wall at 2 m with the default exposure; for ToF cameras
    the optical power is derived from it through eq. 2-9, for stereo cameras
    it fixes the sub-pixel matching noise. ``lens_sigma_px`` is the in-focus
    optical blur (Gaussian PSF sigma); ``hyperfocal_mm`` and
    ``output_step_mm`` become the default ``defocus`` and ``quantization``
    effects of the profile's built-in model (sim/effects ``default_effects``).
    """

    name: str
    vendor: str
    model: str
    technology: Literal["tof", "stereo"]
    width: int
    height: int
    fov_h_deg: float
    fov_v_deg: float
    pixel_pitch_um: float
    wavelength_nm: float
    frame_rate_hz: float
    exposure_us: float
    noise_mm_at_2m: float
    hyperfocal_mm: float
    min_range_mm: float
    max_range_mm: float
    confidence_dtype: Literal["float32", "uint16"]
    lens_sigma_px: float = 0.5
    output_step_mm: float = 0.0
    # ToF (eq. 2-9)
    modulation_mhz: float = 0.0
    modulation_contrast: float = 0.5
    ambient_ratio: float = 0.2
    saturation_ratio: float = 40.0
    confidence_threshold_ratio: float = 0.01
    # active stereo
    baseline_mm: float = 0.0
    disparity_step_px: float = 1.0 / 32.0
    texture_threshold: float = 0.05
    angle_noise_gain: float = 0.1

    def with_overrides(self, overrides: dict[str, Any]) -> CameraProfile:
        """Copy with fields replaced; unknown names raise KeyError naming them."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise KeyError(", ".join(unknown))
        return dataclasses.replace(self, **overrides)


PROFILES: dict[str, CameraProfile] = {
    "blaze101": CameraProfile(
        name="blaze101", vendor="Basler", model="blaze-101", technology="tof",
        width=640, height=480, fov_h_deg=67.0, fov_v_deg=51.0, pixel_pitch_um=10.0,
        wavelength_nm=940.0, frame_rate_hz=30.0, exposure_us=1000.0,
        noise_mm_at_2m=1.0, hyperfocal_mm=400.0, min_range_mm=300.0, max_range_mm=10000.0,
        confidence_dtype="uint16", lens_sigma_px=0.71, modulation_mhz=100.0,
    ),
    "amt100": CameraProfile(
        name="amt100", vendor="Schmersal", model="AM-T100", technology="tof",
        width=640, height=480, fov_h_deg=67.0, fov_v_deg=51.0, pixel_pitch_um=10.0,
        wavelength_nm=850.0, frame_rate_hz=60.0, exposure_us=1000.0,
        noise_mm_at_2m=0.8, hyperfocal_mm=600.0, min_range_mm=300.0, max_range_mm=6000.0,
        confidence_dtype="uint16", lens_sigma_px=0.46, output_step_mm=1.0, modulation_mhz=100.0,
    ),
    "flexx2": CameraProfile(
        name="flexx2", vendor="pmd", model="flexx2 VGA", technology="tof",
        width=224, height=172, fov_h_deg=56.0, fov_v_deg=44.0, pixel_pitch_um=17.5,
        wavelength_nm=940.0, frame_rate_hz=30.0, exposure_us=1000.0,
        noise_mm_at_2m=2.0, hyperfocal_mm=200.0, min_range_mm=100.0, max_range_mm=7000.0,
        confidence_dtype="uint16", lens_sigma_px=0.39, modulation_mhz=60.0,
    ),
    "d455": CameraProfile(
        name="d455", vendor="Intel", model="RealSense D455", technology="stereo",
        width=640, height=480, fov_h_deg=75.0, fov_v_deg=62.0, pixel_pitch_um=3.0,
        wavelength_nm=850.0, frame_rate_hz=30.0, exposure_us=8500.0,
        noise_mm_at_2m=10.0, hyperfocal_mm=500.0, min_range_mm=600.0, max_range_mm=6000.0,
        confidence_dtype="float32", lens_sigma_px=0.60, output_step_mm=1.0, baseline_mm=95.0,
    ),
}

SOURCES: dict[str, dict[str, str]] = {
    "blaze101": {
        "width/height/fov/wavelength/frame_rate": T61,
        "min_range/max_range": T61 + ": measurement range 0.3 to 10 m",
        "noise_mm_at_2m": T61 + ": precision < 1 mm up to 5.5 m; 1.0 mm taken as the centre value",
        "hyperfocal_mm": "Thesis 2024, 6.6: 40 cm hyperfocal distance",
        "pixel_pitch_um": "Sony IMX556 sensor: 10 um",
        "confidence_dtype": "pylon blaze Confidence component is Mono16",
        "lens_sigma_px": "calibrated: SFR10 of the Gaussian-blurred pixel = sensor resolution / imagery "
        "resolution of Thesis 2024, Table 6-3 (0.102 / 0.23 deg)",
        "modulation_mhz/exposure_us/contrast/ambient/saturation": "assumption",
    },
    "amt100": {
        "width/height/fov/wavelength/frame_rate": T61,
        "max_range": T61 + ": 6 m",
        "noise_mm_at_2m": "assumption: Thesis 2024, 6.6 finds the lowest depth noise of the four",
        "hyperfocal_mm": "Thesis 2024, 6.6: 60 cm",
        "output_step_mm": "Thesis 2024, Table 6-1: stores integer millimetres",
        "lens_sigma_px": "calibrated to Thesis 2024, Table 6-3 (0.105 / 0.17 deg)",
        "pixel_pitch_um/modulation_mhz/exposure_us/contrast/ambient/saturation/min_range": "assumption",
    },
    "flexx2": {
        "width/height/fov/wavelength": T61,
        "frame_rate": T61 + ": < 60 fps; 30 fps use case assumed",
        "min_range/max_range": T61 + ": 0.1 to 7 m",
        "noise_mm_at_2m": "assumption: 1 % of distance at 2 m",
        "hyperfocal_mm": "Thesis 2024, 6.6: 20 cm",
        "lens_sigma_px": "calibrated to Thesis 2024, Table 6-3 (0.25 / 0.37 deg)",
        "pixel_pitch_um/modulation_mhz/exposure_us/contrast/ambient/saturation": "assumption",
    },
    "d455": {
        "width/height/fov/wavelength": T61 + " (FOV as used in Thesis 2024)",
        "frame_rate": T61 + ": < 90 fps; 30 fps default stream assumed",
        "min_range/max_range": T61 + ": 0.6 to 6 m",
        "hyperfocal_mm": "Grunnet-Jepsen et al. 2023 (Thesis 2024, 6.2): 500 mm",
        "baseline_mm": "Intel D455 datasheet: 95 mm",
        "output_step_mm": "librealsense z16 depth, 1 mm units",
        "lens_sigma_px": "calibrated to Thesis 2024, Table 6-3 (0.117 / 0.23 deg)",
        "disparity_step_px": "assumption: 1/32 px sub-pixel disparity",
        "texture_threshold": "assumption: local IR contrast below which matching fails",
        "angle_noise_gain": "adapted from Nguyen, Izadi, Lovell 2012 (noise grows with theta^2/(pi/2-theta)^2)",
        "noise_mm_at_2m": "stereo depth resolution z^2 s/(f b) (Thesis 2024, 2.3.2) with s = 0.08 px: about 10 mm at 2 m",
        "pixel_pitch_um/exposure_us": "assumption",
    },
}


def get_profile(name: str) -> CameraProfile:
    """Built-in profile by name; KeyError lists the known names."""
    try:
        return PROFILES[name]
    except KeyError:
        raise KeyError(f"unknown camera profile {name!r}; known: {', '.join(PROFILES)}") from None
