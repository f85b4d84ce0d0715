"""fov_error: the camera's true field of view differs from its datasheet.

The scene is imaged with the true FOV ``fov_deg`` = [h, v] while the run file
reports the datasheet FOV, so evaluations that rely on the datasheet see a
linear scale error. The camera's own calibration knows the true optics, so the
point cloud stays correct. Source: Thesis 2024, 6.4.1 (blaze-101: 65 x 51 deg
instead of 67 x 51; D455: 78 x 62 instead of 75 x 62).
"""

from __future__ import annotations

from pydantic import Field, field_validator

from sim.effects.base import Corners, Effect, EffectParams, Observed

#: the FOV a camera can have, deg
FOV_RANGE_DEG = (10.0, 170.0)


class Params(EffectParams):
    fov_deg: tuple[float, float] = Field(description="true [horizontal, vertical] FOV, deg")

    @field_validator("fov_deg")
    @classmethod
    def _range(cls, value: tuple[float, float]) -> tuple[float, float]:
        lo, hi = FOV_RANGE_DEG
        if not all(lo <= v <= hi for v in value):
            raise ValueError(f"fov_deg must lie in [{lo:g}, {hi:g}] deg, got {list(value)}")
        return value


EFFECT = Effect(
    "fov_error",
    ("tof", "stereo"),
    Params,
    "Thesis 2024, 6.4.1, Table 6-2",
    observed=Observed(why_not="the camera's calibration keeps depth and the cloud right; a checkerboard's corners "
                            "would show it",
                      corners=Corners(("fov_h_deg", "fov_v_deg"), (FOV_RANGE_DEG[0],) * 2, (FOV_RANGE_DEG[1],) * 2,
                                      start=lambda profile: (profile.fov_h_deg, profile.fov_v_deg),
                                      params=lambda x: {"fov_deg": [float(x[0]), float(x[1])]}),
                      procedure="checkerboard"),
    true_fov_deg=lambda p: p.fov_deg,
)
