"""The key figures (docs/keyfigures.md): one definition per name, used by JSON and report alike.

Each figure carries its name, unit, meaning and the source section of its
method, so ``keyfigures.json`` and the report can never drift apart.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict, TypeVar

from labctl.errors import InputError
from labctl.evaluation.conditions import RunConditions
from labctl.evaluation.sections import (
    AcceptancePositionRow,
    AcceptanceVerdict,
    AlignmentSection,
    BoehlerStarRow,
    CaptureRow,
    CheckerboardRow,
    DepthQualityRow,
    DepthSweepRow,
    FaceMaskSection,
    Misalignment,
    RemissionAngleRow,
    SlantedEdgeRow,
    XYNoiseRow,
)
from labctl.evaluation.suitability import CheckResult, StoryVerdict, Suitability
from labctl.jsondoc import optional
from metrics.uncertainty import Component, combined_standard_uncertainty, expanded_uncertainty


@dataclass(frozen=True)
class FigureDef:
    name: str
    unit: str
    meaning: str
    section: str


FIGURES: tuple[FigureDef, ...] = (
    FigureDef("z_trueness_q90_mm", "mm", "Q90 of |mean of stack - reference| over valid pixels, at 2000 mm",
              "Thesis 2024, 4.2.1"),
    FigureDef("z_accuracy_q90_mm", "mm", "Q90 of |single frame - reference| over valid pixels, at 2000 mm", "Thesis 2024, 4.2.1"),
    FigureDef("z_precision_q90_mm", "mm", "Q90 of the per-pixel standard deviation, at 2000 mm", "Thesis 2024, 4.2.1"),
    FigureDef("z_repeatability_center_mm", "mm", "max over the sweep of the centre pixel's standard deviation",
              "Thesis 2024, 4.2.1"),
    FigureDef("surface_primary_sq_mm", "mm", "ISO 25178 Sq of the primary surface at 2000 mm", "Thesis 2024, 4.2.2"),
    FigureDef("surface_waviness_sq_mm", "mm", "ISO 25178 Sq of the waviness surface at 2000 mm", "Thesis 2024, 4.2.2"),
    FigureDef("surface_roughness_sq_mm", "mm", "ISO 25178 Sq of the roughness surface at 2000 mm", "Thesis 2024, 4.2.2"),
    FigureDef("hyperfocal_distance_mm", "mm", "left edge of the sharpness plateau", "Thesis 2024, 5.1.2"),
    FigureDef("best_focus_distance_mm", "mm", "distance of highest sharpness: the nearest within 5 % of the "
              "highest smoothed SFR area, where sharp targets are placed", "Thesis 2024, 5.1.2"),
    FigureDef("intensity_resolution_h_deg", "deg", "imagery resolution of the intensity image, horizontal (SFR10)",
              "Thesis 2024, 5.1.2"),
    FigureDef("intensity_resolution_v_deg", "deg", "imagery resolution of the intensity image, vertical (SFR10)",
              "Thesis 2024, 5.1.2"),
    FigureDef("cloud_resolution_h_deg", "deg", "imagery resolution of the point cloud, horizontal (Boehler star)",
              "Thesis 2024, 5.1.3"),
    FigureDef("cloud_resolution_v_deg", "deg", "imagery resolution of the point cloud, vertical (Boehler star)",
              "Thesis 2024, 5.1.3"),
    FigureDef("pixel_aspect_distortion_pct", "%", "pixel aspect ratio distortion from FOV and sensor size", "Thesis 2024, 5.2"),
    FigureDef("radial_distortion_intensity_w_pct", "%", "checkerboard radial distortion, intensity image, width",
              "Thesis 2024, 5.2"),
    FigureDef("radial_distortion_intensity_h_pct", "%", "checkerboard radial distortion, intensity image, height",
              "Thesis 2024, 5.2"),
    FigureDef("radial_distortion_cloud_w_pct", "%", "checkerboard radial distortion, point cloud, width", "Thesis 2024, 5.2"),
    FigureDef("radial_distortion_cloud_h_pct", "%", "checkerboard radial distortion, point cloud, height", "Thesis 2024, 5.2"),
    FigureDef("x_trueness_q90_mm", "mm", "checkerboard corner spacing vs tile size, x, stack mean", "Thesis 2024, 5.3"),
    FigureDef("y_trueness_q90_mm", "mm", "checkerboard corner spacing vs tile size, y, stack mean", "Thesis 2024, 5.3"),
    FigureDef("x_accuracy_q90_mm", "mm", "checkerboard corner spacing vs tile size, x, single frame", "Thesis 2024, 5.3"),
    FigureDef("y_accuracy_q90_mm", "mm", "checkerboard corner spacing vs tile size, y, single frame", "Thesis 2024, 5.3"),
    FigureDef("x_precision_q90_mm", "mm", "Q90 of the per-pixel std of x on the wall at 2000 mm", "Thesis 2024, 5.3"),
    FigureDef("y_precision_q90_mm", "mm", "Q90 of the per-pixel std of y on the wall at 2000 mm", "Thesis 2024, 5.3"),
    FigureDef("x_repeatability_center_mm", "mm", "max over the sweep of the centre pixel's std of x (x ~ 0 there: "
              "lateral jitter only)", "Thesis 2024, 5.3"),
    FigureDef("y_repeatability_center_mm", "mm", "max over the sweep of the centre pixel's std of y (y ~ 0 there: "
              "lateral jitter only)", "Thesis 2024, 5.3"),
    FigureDef("x_repeatability_off_axis_mm", "mm", "max over the sweep of the std of x halfway from the centre to "
              "the right edge, where x carries the depth noise", "docs/metrics.md, x/y noise"),
    FigureDef("y_repeatability_off_axis_mm", "mm", "max over the sweep of the std of y halfway from the centre to "
              "the bottom edge, where y carries the depth noise", "docs/metrics.md, x/y noise"),
    FigureDef("repeatability_skin_40deg_mm", "mm", "max repeatability over skin-like materials at 40 deg", "Thesis 2024, 5.4"),
    FigureDef("repeatability_skin_70deg_mm", "mm", "max repeatability over skin-like materials at 70 deg", "Thesis 2024, 5.4"),
    FigureDef("ied_pixels_at_hyperfocal", "px", "inter-eye distance (62.5 mm) coverage at the hyperfocal distance, "
              "face at the image centre (pinhole: 62.5 mm x f / d, f = (W / 2) / tan(FOV_h / 2))", "Thesis 2024, Ch. 3, 6.6"),
    FigureDef("ied_pixels_at_hyperfocal_angular", "px", "the same with the mean angular pixel size FOV_h / W "
              "(Thesis 2024, eq. 6-2); over-counts at the image centre", "docs/suitability.md"),
)

#: where the datasheet-comparable figures are defined
DQT = "Intel librealsense tools/depth-quality (Depth Quality Tool)"
BASLER = "Basler blaze docs: Depth Quality Metrics; Accuracy and Precision"


def _vendor_figures(distance_mm: int) -> tuple[FigureDef, ...]:
    d = f"on the wall at {distance_mm} mm"
    return (
        FigureDef(f"fill_rate_{distance_mm}mm_pct", "%", f"valid pixels in the centred 40 % ROI, {d}", DQT),
        FigureDef(f"z_accuracy_{distance_mm}mm_pct", "%",
                  f"median signed error vs the distance from the camera's depth origin (laser minus "
                  f"devices.camera.depth_origin_offset_mm), % of it, 0.5 % trimmed each end, {d}", DQT),
        FigureDef(f"plane_fit_rms_{distance_mm}mm_mm", "mm",
                  f"RMS of point-to-plane distances in the 40 % ROI, 0.5 % trimmed each end, {d}", DQT),
        FigureDef(f"subpixel_rms_{distance_mm}mm_px", "px",
                  f"RMS of disparity deviations from the fitted plane (stereo only), {d}", DQT),
        FigureDef(f"spatial_precision_{distance_mm}mm_mm", "mm",
                  f"RMS of one frame's depth about its plane, centre 40 x 40 px, mean over frames, {d}", BASLER),
        FigureDef(f"temporal_precision_{distance_mm}mm_mm", "mm",
                  f"quadratic mean of the per-pixel std over the stack, centre 40 x 40 px, {d}", BASLER),
    )


#: the datasheet-comparable figures, at the distances the vendors quote
VENDOR_FIGURES: tuple[FigureDef, ...] = _vendor_figures(1000) + _vendor_figures(2000)
#: figures only a stereo camera has (null for the others)
STEREO_ONLY = frozenset(f.name for f in VENDOR_FIGURES if f.name.startswith("subpixel_rms_"))
VDI = "VDI/VDE 2634 Part 2"
#: the acceptance-test quantities (largest magnitude over all measurements, each the mean of frames_per_measurement
#: frames)
ACCEPTANCE_FIGURES: tuple[FigureDef, ...] = (
    FigureDef("probing_error_form_mm", "mm", "max over spheres and measurements (each the mean of "
              "frames_per_measurement frames) of the range of radial deviations from the fitted sphere (P_F)", VDI),
    FigureDef("probing_error_size_mm", "mm", "fitted minus calibrated sphere diameter, largest magnitude over "
              "spheres and measurements (P_S)", VDI),
    FigureDef("sphere_spacing_error_mm", "mm", "measured minus calibrated ball-bar centre distance, largest "
              "magnitude over positions and measurements (SD)", VDI),
    FigureDef("flatness_error_mm", "mm", "max over positions and measurements of the range of deviations from the "
              "least-squares plane of the flat plate (F)", VDI),
)
FIGURES = FIGURES + VENDOR_FIGURES + ACCEPTANCE_FIGURES
FIGURE_BY_NAME = {f.name: f for f in FIGURES}

#: figures where a larger value is better (coverage and fill rates)
HIGHER_IS_BETTER = frozenset({"ied_pixels_at_hyperfocal", "ied_pixels_at_hyperfocal_angular"}
                              | {f.name for f in VENDOR_FIGURES if f.name.startswith("fill_rate_")})
#: figures that are neither better high nor low: the distance the camera is sharpest at
NO_BETTER_DIRECTION = frozenset({"best_focus_distance_mm"})
#: signed figures, errors of either sign: closer to 0 is better (the pixel aspect and radial distortions, Z accuracy,
#: the VDI/VDE 2634-2 size and spacing errors P_S and SD)
CLOSER_TO_ZERO_IS_BETTER = frozenset(
    {"pixel_aspect_distortion_pct", "probing_error_size_mm", "sphere_spacing_error_mm"}
    | {f.name for f in FIGURES if f.name.startswith(("radial_distortion_", "z_accuracy_")) and f.name.endswith("_pct")})


def better_direction(name: str) -> str:
    """How a figure improves: "higher", "none", "zero" (a signed figure: closer to 0) or "lower"."""
    if name in HIGHER_IS_BETTER:
        return "higher"
    if name in CLOSER_TO_ZERO_IS_BETTER:
        return "zero"
    return "none" if name in NO_BETTER_DIRECTION else "lower"


@dataclass(frozen=True)
class FigureValue:
    """A figure as the evaluation found it: its value, the steps it comes from and its uncertainty budget
    (standard components in the figure's unit; empty where the uncertainty is not estimated)."""

    value: float | None
    source: list[str]
    budget: tuple[Component, ...] = ()


class BudgetLine(TypedDict):
    """One component of a figure's ``uncertainty_budget``: its name and standard uncertainty (figure's unit)."""

    component: str
    value: float | None


def clean(value: float | None) -> float | None:
    """JSON-safe number: None for missing or non-finite values."""
    if value is None or not math.isfinite(value):
        return None
    return float(value)


@dataclass(kw_only=True)
class FigureEntry:
    """One figure of ``keyfigures.json``: its value (null where not measured), unit, the steps it comes from
    (comma separated), its meaning, its flags (``{"check", "message"}`` each: the plausibility checks it fails,
    or why it is null), which way it improves (``better``: :func:`better_direction`), its standard uncertainty
    (same unit), the expanded uncertainty (k = 2) and the budget they combine (docs/keyfigures.md; null and
    empty where the uncertainty is not estimated)."""

    value: float | None
    unit: str
    source: str
    meaning: str
    flags: list[dict[str, str]]
    better: str
    uncertainty: float | None = None
    expanded_uncertainty: float | None = None
    uncertainty_budget: list[BudgetLine] = dataclasses.field(default_factory=list)


def standard_uncertainty(value: FigureValue) -> float | None:
    """A figure's standard uncertainty combined from its budget (metrics/uncertainty.py) where the value and every
    component are finite, else None (not estimated)."""
    return clean(combined_standard_uncertainty(value.budget)) if clean(value.value) is not None else None


def figure_entry(fig: FigureDef, value: FigureValue, flags: list[dict[str, str]]) -> FigureEntry:
    """The entry of one figure, with its :func:`standard_uncertainty`, the expanded uncertainty (k = 2) and the
    budget they combine; null and empty where the uncertainty is not estimated."""
    u = standard_uncertainty(value)
    return FigureEntry(value=clean(value.value), unit=fig.unit, source=",".join(value.source), meaning=fig.meaning,
                       flags=flags, better=better_direction(fig.name), uncertainty=u,
                       expanded_uncertainty=None if u is None else expanded_uncertainty(u),
                       uncertainty_budget=[] if u is None else [{"component": c.name, "value": c.value}
                                                                for c in value.budget])


@dataclass(kw_only=True)
class CameraDescription:
    """``camera`` of keyfigures.json: the camera as the run file records it (its device identity, ``unknown``
    where the file has none; sensor size, FOV, frame rate, wavelength) and whether the run was simulated. Read
    back from a keyfigures.json that lacks them, the identity reads as ``unknown``, the numbers as None and
    ``simulated`` as False."""

    model: str = "unknown"
    serial: str = "unknown"
    firmware: str = "unknown"
    backend: str = "unknown"
    width: int | None = None
    height: int | None = None
    fov_deg: list[float] | None = None
    frame_rate_hz: float | None = None
    wavelength_nm: float | None = None
    simulated: bool = False


#: the version of keyfigures.json's layout (docs/keyfigures.schema.json): the minor number grows with keys added,
#: the major number with a change that breaks a reader of the previous layout
SCHEMA_VERSION = "1.2"


@dataclass(kw_only=True)
class KeyFiguresDocument:
    """``keyfigures.json`` (docs/keyfigures.md): the camera, every defined figure, the suitability verdicts and
    the version of the file's layout, then the evaluated runs, notes and the sections of the procedures the runs hold
    (their records: labctl/evaluation/sections.py); a procedure's section is absent when the runs lack it. Read
    back from a file written before the layout had a version, ``schema_version`` reads as ``"0"``."""

    camera: CameraDescription
    figures: dict[str, FigureEntry]
    suitability: Suitability
    schema_version: str = SCHEMA_VERSION
    runs: list[str] | None = optional()
    conditions: list[RunConditions] | None = optional()
    notes: list[str] | None = optional()
    depth_sweep: list[DepthSweepRow] | None = optional()
    slanted_edge: list[SlantedEdgeRow] | None = optional()
    capture: list[CaptureRow] | None = optional()
    alignment: AlignmentSection | None = optional()
    depth_quality: list[DepthQualityRow] | None = optional()
    acceptance_test: dict[str, AcceptanceVerdict] | None = optional()
    acceptance_positions: list[AcceptancePositionRow] | None = optional()
    checkerboard: list[CheckerboardRow] | None = optional()
    boehler_star: list[BoehlerStarRow] | None = optional()
    xy_noise: list[XYNoiseRow] | None = optional()
    remission_angle: list[RemissionAngleRow] | None = optional()
    misalignment: Misalignment | None = optional()
    face_mask: FaceMaskSection | None = optional()


def keyfigures_document(
    camera: CameraDescription, values: dict[str, FigureValue], suitability: Suitability,
    flags: dict[str, list[dict[str, str]]] | None = None,
) -> KeyFiguresDocument:
    """The ``keyfigures.json`` document: every defined figure, null where not measured, with its
    plausibility flags (an empty list where it passes every check)."""
    unknown = set(values) - set(FIGURE_BY_NAME)
    if unknown:
        raise KeyError(f"undefined key figures: {sorted(unknown)}")
    figures = {}
    for fig in FIGURES:
        figures[fig.name] = figure_entry(fig, values.get(fig.name, FigureValue(None, [])),
                                         list((flags or {}).get(fig.name, [])))
    return KeyFiguresDocument(camera=camera, figures=figures, suitability=suitability)


Record = TypeVar("Record")


def read_keyfigures(path: Path) -> KeyFiguresDocument:
    """A ``keyfigures.json`` written by ``labctl evaluate``, read back (a figure's missing fields read as empty,
    its missing uncertainties as None and budget as empty, its missing ``better`` as this version defines it,
    the procedure sections into their records without the keys of other labctl versions); InputError naming
    the file when it is missing, not JSON, or has no ``camera`` / ``figures``."""
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path.parent} has no keyfigures.json: give output directories of 'labctl evaluate'") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(data, dict) or "figures" not in data or "camera" not in data:
        raise InputError(f"{path} is not a labctl keyfigures.json (no 'camera'/'figures')")
    figures = {name: FigureEntry(value=f.get("value"), unit=f.get("unit", ""), source=f.get("source", ""),
                                 meaning=f.get("meaning", ""), flags=f.get("flags", []),
                                 better=f.get("better", better_direction(name)), uncertainty=f.get("uncertainty"),
                                 expanded_uncertainty=f.get("expanded_uncertainty"),
                                 uncertainty_budget=f.get("uncertainty_budget", []))
               for name, f in data["figures"].items()}
    hints = typing.get_type_hints(KeyFiguresDocument)
    try:
        sections = {f.name: _section(hints[f.name], data.get(f.name)) for f in dataclasses.fields(KeyFiguresDocument)
                    if f.name not in ("schema_version", "camera", "figures", "suitability")}
        return KeyFiguresDocument(schema_version=str(data.get("schema_version", "0")),
                                  camera=_known_fields(CameraDescription, data["camera"]), figures=figures,
                                  suitability=_suitability(data.get("suitability", {})), **sections)
    except (TypeError, AttributeError) as exc:
        raise InputError(f"{path} is not a labctl keyfigures.json ({exc})") from None


def _section(hint: object, value: object) -> object:
    """``value`` (from JSON) as the type ``hint`` of a document field: a record (``TypedDict``) with only its
    keys (those of other labctl versions left out), a list or dict item by item, anything else as it is."""
    if isinstance(hint, types.UnionType):  # X | None: the section when it is present
        hint = next(arg for arg in typing.get_args(hint) if arg is not type(None))
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if typing.is_typeddict(hint) and isinstance(value, dict):
        keys = typing.get_type_hints(hint)
        return {k: _section(keys[k], v) for k, v in value.items() if k in keys}
    if origin is list and isinstance(value, list):
        return [_section(args[0], item) for item in value]
    if origin is dict and isinstance(value, dict):
        return {k: _section(args[1], item) for k, item in value.items()}
    return value


def _known_fields(record: type[Record], data: Mapping[str, object]) -> Record:
    """``record`` from the keys of ``data`` that are its fields (those of other labctl versions left out)."""
    names = {f.name for f in dataclasses.fields(record)}  # type: ignore[arg-type]  # a dataclass
    return record(**{k: v for k, v in data.items() if k in names})


def _suitability(data: dict[str, Any]) -> Suitability:
    """The ``suitability`` section read back."""
    stories = {key: _known_fields(StoryVerdict, {**story, "checks": [_known_fields(CheckResult, c)
                                                                   for c in story.get("checks", [])]})
               for key, story in data.get("stories", {}).items()}
    return Suitability(standard=data.get("standard", ""), stories=stories)
