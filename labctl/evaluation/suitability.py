"""Suitability of a camera for facial biometrics: one verdict per user story of Thesis 2024, Table 3-1.

Requirements and where they come from (docs/suitability.md gives the reasoning):

* radial distortion <= 5 % for 1:N and <= 7 % for 1:1 face recognition, and
  an inter-eye distance (IED) >= 90 px: ISO/IEC 39794-5:2019 Annex D, written
  for 2D face images and applied to the 3D camera's images as in Table 3-1;
* pixel aspect ratio within +-10 %: Hedberg (2020), citing Sun (2014), via Table 3-1;
* depth precision and trueness on the face: no standard sets them (ISO/IEC
  39794-5 and 19794-5 Amd 2 define how 3D face data are stored, ISO/IEC
  29794-5 the quality of 2D face images, ISO/IEC 30107-3 how presentation
  attack detection is tested), so the limits are judgements, marked as such,
  set against published data: the 3D scans face recognition was developed on
  (FRGC: Minolta Vivid 910, depth accuracy about 0.1 mm; Phillips et al. 2005)
  and the Kinect v1 (random depth error of a few mm at 1 m; Khoshelham & Oude
  Elberink 2012) whose 3D recognition falls well short of those scans (Min,
  Kose & Dugelay 2014).

The IED is counted for a face at the image centre (pinhole model,
metrics/sharpness.py) at the hyperfocal distance; depth precision and
trueness come from the first wall step at or beyond that distance (noise
grows with distance, so a pass there holds for the face).

A check is decided with the figures' expanded uncertainties U (k = 2) where they state one, by the guarded
decision rule of JCGM 106:2012, clause 8 (guard bands of width U) and ISO 14253-1:2017 (docs/suitability.md):
``pass`` where the value lies inside the limit by more than U, ``fail`` where it lies outside by more than U,
``marginal`` where the limit is within U of it (neither conformity nor non-conformity is shown); a figure
without an uncertainty is decided on its value alone. ``not_evaluated`` where a figure is missing. A story's
verdict is ``fail`` if any check fails, else ``not_evaluated`` if one is, else ``marginal`` if one is, else
``pass``; its ``summary`` says why in one line.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from metrics.uncertainty import conformity

IED_MIN_PX = 90.0
DISTORTION_1_TO_N_PCT = 5.0
DISTORTION_1_TO_1_PCT = 7.0
PIXEL_AR_LIMIT_PCT = 10.0
#: judgements (see the module docstring): depth precision (Q90 of the per-pixel std) and trueness on the face
PRECISION_RECOGNITION_MM = 1.0
TRUENESS_RECOGNITION_MM = 2.0
PRECISION_LANDMARKS_MM = 2.0
PRECISION_LIVENESS_MM = 5.0

ISO_39794 = "ISO/IEC 39794-5:2019 Annex D (2D face images), applied to the 3D camera (Thesis 2024, Table 3-1)"
HEDBERG = "Hedberg 2020 citing Sun 2014, via Thesis 2024, Table 3-1"
DEPTH_JUDGEMENT = ("judgement: between FRGC scans (~0.1 mm, Phillips et al. 2005) and Kinect v1 (a few mm at 1 m, "
                   "Khoshelham & Oude Elberink 2012; weaker 3D recognition, Min et al. 2014)")
LANDMARK_JUDGEMENT = "judgement: a tenth of the ~20 mm nose relief the 3D landmark check relies on"
LIVENESS_JUDGEMENT = "judgement: the face's relief (~20-30 mm) must stand out from a flat photo by > 4 sigma"

#: extra inputs (not key figures) the depth checks read; see :func:`face_depth_values`
FACE_DISTANCE = "face_distance_mm"
FACE_WALL_STEP = "face_wall_step_mm"
FACE_PRECISION = "z_precision_q90_at_face_mm"
FACE_TRUENESS = "z_trueness_q90_at_face_mm"


@dataclass(frozen=True)
class Check:
    requirement: str
    figures: tuple[str, ...]
    limit: float
    kind: str  # "max_abs": every |figure| <= limit; "min": every figure >= limit
    source: str
    judgement: bool = False


def _distortion(figures: tuple[str, ...], limit: float) -> Check:
    return Check(f"radial distortion <= {limit:g} %", figures, limit, "max_abs", ISO_39794)


IED = Check(f"inter-eye distance >= {IED_MIN_PX:g} px (face at the image centre, hyperfocal distance)",
            ("ied_pixels_at_hyperfocal",), IED_MIN_PX, "min", ISO_39794)
PIXEL_AR = Check(f"pixel aspect ratio within +-{PIXEL_AR_LIMIT_PCT:g} %", ("pixel_aspect_distortion_pct",),
               PIXEL_AR_LIMIT_PCT, "max_abs", HEDBERG)


def _precision(limit: float, source: str) -> Check:
    return Check(f"depth precision (Q90 of the per-pixel std) <= {limit:g} mm on the face", (FACE_PRECISION,),
                 limit, "max_abs", source, judgement=True)


TRUENESS = Check(f"depth trueness (Q90) <= {TRUENESS_RECOGNITION_MM:g} mm on the face", (FACE_TRUENESS,),
                 TRUENESS_RECOGNITION_MM, "max_abs", DEPTH_JUDGEMENT, judgement=True)
CLOUD = ("radial_distortion_cloud_w_pct", "radial_distortion_cloud_h_pct")
INTENSITY = ("radial_distortion_intensity_w_pct", "radial_distortion_intensity_h_pct")
RECOGNITION_DEPTH = [_precision(PRECISION_RECOGNITION_MM, DEPTH_JUDGEMENT), TRUENESS]

STORIES: dict[str, tuple[str, list[Check], tuple[str, ...]]] = {
    "3d_face_recognition_1_to_n": ("3D face recognition, 1:N identification",
                                   [_distortion(CLOUD, DISTORTION_1_TO_N_PCT), IED, PIXEL_AR, *RECOGNITION_DEPTH], ()),
    "3d_face_recognition_1_to_1": ("3D face recognition, 1:1 verification",
                                   [_distortion(CLOUD, DISTORTION_1_TO_1_PCT), IED, PIXEL_AR, *RECOGNITION_DEPTH], ()),
    "pad_makeup_nir": ("make-up attack PAD: faces detected in the camera's NIR image, landmarks checked in 3D",
                       [_distortion(INTENSITY, DISTORTION_1_TO_N_PCT), IED, PIXEL_AR,
                        _precision(PRECISION_LANDMARKS_MM, LANDMARK_JUDGEMENT)], ()),
    "pad_makeup_rgb": ("make-up attack PAD: faces detected by an RGB camera, landmarks checked in 3D",
                       [_precision(PRECISION_LANDMARKS_MM, LANDMARK_JUDGEMENT)],
                       ("cloud_resolution_h_deg", "cloud_resolution_v_deg")),
    "pad_light": ("PAD light: is the face three-dimensional (photo, video)?",
                  [_precision(PRECISION_LIVENESS_MM, LIVENESS_JUDGEMENT)], ("surface_waviness_sq_mm",)),
    "3d_support": ("3D support of other sensors: area coverage over a large volume", [],
                   ("z_trueness_q90_mm", "z_repeatability_center_mm")),
}

@dataclass(kw_only=True)
class CheckResult:
    """One requirement of a user story checked: its text, ``pass`` / ``fail`` / ``marginal`` / ``not_evaluated``,
    the limit, the figures' values (None where not measured), its source, whether the limit is a judgement and the
    figures' expanded uncertainties (read back from an older file: empty)."""

    requirement: str
    status: str
    limit: float
    values: dict[str, float | None]
    source: str
    judgement: bool
    #: the figures' expanded uncertainties (k = 2) the decision used; None where a figure states none
    uncertainties: dict[str, float | None] = field(default_factory=dict)


@dataclass(kw_only=True)
class StoryVerdict:
    """A user story's verdict (``pass``, ``fail``, ``marginal``, ``not_evaluated``, ``no_numeric_requirement``), its one-line
    reason, its checks and the figures it relies on. Read back from a file, what the file lacks reads as empty."""

    description: str = ""
    verdict: str
    summary: str = ""
    checks: list[CheckResult] = field(default_factory=list)
    figures: dict[str, float | None] = field(default_factory=dict)


@dataclass(kw_only=True)
class Suitability:
    """``suitability`` of keyfigures.json: the standards and judgements the limits come from, and the verdict of
    every user story."""

    standard: str = ""
    stories: dict[str, StoryVerdict] = field(default_factory=dict)


def face_wall_row(values: Mapping[str, float | None], depth_rows: Sequence[Mapping[str, Any]]) -> Mapping[str, Any] | None:
    """The depth row the face's depth checks read: the first wall step at or beyond the face distance (the
    hyperfocal distance, where the IED is counted) that has valid pixels; None when there is none."""
    face = values.get("hyperfocal_distance_mm")
    if face is None or not math.isfinite(face):
        return None
    beyond = [r for r in depth_rows if _finite(r["reference_mm"]) and r["reference_mm"] >= face
              and _finite(r["precision_q90_mm"])]  # a wall step with no valid pixel says nothing
    return min(beyond, key=lambda r: r["reference_mm"]) if beyond else None


def face_depth_values(values: Mapping[str, float | None], depth_rows: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Depth precision and trueness on the face, from :func:`face_wall_row`, with the face's and the wall's
    distance. Empty when there is no such row."""
    row = face_wall_row(values, depth_rows)
    if row is None:
        return {}
    return {FACE_DISTANCE: float(values["hyperfocal_distance_mm"]), FACE_WALL_STEP: float(row["reference_mm"]),
            FACE_PRECISION: row["precision_q90_mm"], FACE_TRUENESS: row["trueness_q90_mm"]}


def _finite(value: float | None) -> bool:
    return value is not None and math.isfinite(value)


def _evaluate(check: Check, values: Mapping[str, float | None], expanded: Mapping[str, float | None]) -> CheckResult:
    numbers = {name: values.get(name) for name in check.figures}
    uncertainties = {name: expanded.get(name) if _finite(expanded.get(name)) else None for name in check.figures}
    if not all(_finite(v) for v in numbers.values()):
        status = "not_evaluated"
    else:
        statuses = {conformity(numbers[n], check.limit, uncertainties[n], check.kind) for n in check.figures}
        status = next(s for s in ("fail", "marginal", "pass") if s in statuses)
    requirement = check.requirement
    if FACE_PRECISION in check.figures or FACE_TRUENESS in check.figures:
        wall, face = values.get(FACE_WALL_STEP), values.get(FACE_DISTANCE)
        if wall is not None and face is not None:
            requirement += f" (wall at {wall:.0f} mm, face at {face:.0f} mm)"
    return CheckResult(requirement=requirement, status=status, limit=check.limit, values=numbers, source=check.source,
                       judgement=check.judgement, uncertainties=uncertainties)


def _number(value: float | None, expanded: float | None = None) -> str:
    if value is None:
        return "n/a"
    return f"{value:.3g}" if expanded is None else f"{value:.3g} +- {expanded:.2g}"


def _summary(verdict: str, results: list[CheckResult], informative: dict[str, float | None]) -> str:
    """One line: why the story got its verdict."""
    if verdict == "no_numeric_requirement":
        return "no numeric requirement; relies on " + ", ".join(informative)
    if verdict == "pass":
        return "meets its requirement" if len(results) == 1 else f"meets all {len(results)} requirements"
    parts = []
    for r in results:
        if r.status != verdict:
            continue
        if verdict == "not_evaluated":
            parts.append(", ".join(name for name, v in r.values.items() if v is None))
            continue
        shown = ", ".join(_number(v, r.uncertainties.get(name)) for name, v in r.values.items())
        parts.append(f"{re.sub(r' [(][^)]*[)]', '', r.requirement)}: {shown}")
    lead = {"fail": "fails ", "not_evaluated": "not measured: ",
            "marginal": "marginal (the limit lies within the expanded uncertainty): "}[verdict]
    return lead + "; ".join(parts)


def suitability(values: Mapping[str, float | None], expanded: Mapping[str, float | None] | None = None) -> Suitability:
    """Per user story: its checks with their numbers, uncertainties and sources, a verdict and its one-line reason
    (``suitability`` of keyfigures.json). ``values``: the key figures plus :func:`face_depth_values`;
    ``expanded``: their expanded uncertainties (k = 2), where they state one."""
    stories: dict[str, StoryVerdict] = {}
    for key, (description, checks, informative) in STORIES.items():
        results = [_evaluate(c, values, expanded or {}) for c in checks]
        statuses = {r.status for r in results}
        if not checks:
            verdict = "no_numeric_requirement"
        else:
            verdict = next(s for s in ("fail", "not_evaluated", "marginal", "pass") if s in statuses)
        figures = {name: values.get(name) for name in informative}
        stories[key] = StoryVerdict(description=description, verdict=verdict, summary=_summary(verdict, results, figures),
                                    checks=results, figures=figures)
    return Suitability(standard="Thesis 2024, Table 3-1 user stories; ISO/IEC 39794-5:2019 Annex D for distortion and "
                                "IED; depth limits are judgements (docs/suitability.md)", stories=stories)
