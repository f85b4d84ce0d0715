"""Suitability of a camera for facial biometrics (Thesis 2024, Ch. 3, 6.6, Table 3-1; ISO/IEC 39794-5 Annex D).

Requirements (Thesis 2024, Table 3-1, from ISO/IEC 39794-5 for 2D face images):

* radial distortion <= 5 % for 1:N and <= 7 % for 1:1 face recognition;
* inter-eye distance >= 90 px (62.5 mm IED at the hyperfocal distance, eq. 6-2);
* pixel aspect ratio within +-10 %.

Each user story of Table 3-1 with numeric requirements gets these checks on
the key figures it depends on (the point cloud for 3D face recognition, the
NIR intensity image for the make-up PAD that detects faces in it). A check is
``pass``, ``fail`` or ``not_evaluated`` (a figure is missing), and a story's
verdict is ``fail`` if any check fails, ``pass`` if all pass, otherwise
``not_evaluated``. Stories without numeric requirements (3D support, PAD
light, make-up PAD with an RGB camera) are listed with the figures they rely on.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

IED_MIN_PX = 90.0
DISTORTION_1_TO_N_PCT = 5.0
DISTORTION_1_TO_1_PCT = 7.0
PIXEL_AR_LIMIT_PCT = 10.0  # pixel aspect ratio: within +-10 %


@dataclass(frozen=True)
class Check:
    requirement: str
    figures: tuple[str, ...]
    limit: float
    kind: str  # "max_abs": every |figure| <= limit; "min": every figure >= limit


def _checks(distortion_figures: tuple[str, ...], distortion_limit: float) -> list[Check]:
    return [
        Check(f"radial distortion <= {distortion_limit:g} %", distortion_figures, distortion_limit, "max_abs"),
        Check(f"inter-eye distance >= {IED_MIN_PX:g} px at the hyperfocal distance", ("ied_pixels_at_hyperfocal",),
              IED_MIN_PX, "min"),
        Check(f"pixel aspect ratio within +-{PIXEL_AR_LIMIT_PCT:g} %", ("pixel_aspect_distortion_pct",),
              PIXEL_AR_LIMIT_PCT, "max_abs"),
    ]


CLOUD = ("radial_distortion_cloud_w_pct", "radial_distortion_cloud_h_pct")
INTENSITY = ("radial_distortion_intensity_w_pct", "radial_distortion_intensity_h_pct")

STORIES: dict[str, tuple[str, list[Check], tuple[str, ...]]] = {
    "3d_face_recognition_1_to_n": ("3D face recognition, 1:N identification", _checks(CLOUD, DISTORTION_1_TO_N_PCT), ()),
    "3d_face_recognition_1_to_1": ("3D face recognition, 1:1 verification", _checks(CLOUD, DISTORTION_1_TO_1_PCT), ()),
    "pad_makeup_nir": ("make-up attack PAD: faces detected in the camera's NIR image, landmarks checked in 3D",
                       _checks(INTENSITY, DISTORTION_1_TO_N_PCT), ()),
    "pad_makeup_rgb": ("make-up attack PAD: faces detected by an RGB camera, landmarks checked in 3D", [],
                       ("z_trueness_q90_mm", "z_precision_q90_mm", "cloud_resolution_h_deg", "cloud_resolution_v_deg")),
    "pad_light": ("PAD light: is the face three-dimensional (photo, video)?", [],
                  ("z_precision_q90_mm", "surface_waviness_sq_mm")),
    "3d_support": ("3D support of other sensors: area coverage over a large volume", [],
                   ("z_trueness_q90_mm", "z_repeatability_center_mm")),
}


def _evaluate(check: Check, values: Mapping[str, float | None]) -> dict[str, Any]:
    numbers = {name: values.get(name) for name in check.figures}
    present = [v for v in numbers.values() if v is not None and math.isfinite(v)]
    if len(present) < len(numbers):
        status = "not_evaluated"
    elif check.kind == "max_abs":
        status = "pass" if all(abs(v) <= check.limit for v in present) else "fail"
    else:
        status = "pass" if all(v >= check.limit for v in present) else "fail"
    return {"requirement": check.requirement, "status": status, "limit": check.limit, "values": numbers}


def suitability(values: Mapping[str, float | None]) -> dict[str, Any]:
    """Per user story: its checks with their numbers and a verdict (``suitability`` of keyfigures.json)."""
    stories = {}
    for key, (description, checks, informative) in STORIES.items():
        results = [_evaluate(c, values) for c in checks]
        statuses = {r["status"] for r in results}
        if not checks:
            verdict = "no_numeric_requirement"
        elif "fail" in statuses:
            verdict = "fail"
        elif statuses == {"pass"}:
            verdict = "pass"
        else:
            verdict = "not_evaluated"
        stories[key] = {
            "description": description,
            "verdict": verdict,
            "checks": results,
            "figures": {name: values.get(name) for name in informative},
        }
    return {"standard": "ISO/IEC 39794-5 Annex D via Thesis 2024, Table 3-1", "stories": stories}
