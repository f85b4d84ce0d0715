"""Evaluation of ``capture`` steps (``labctl device camera``): what one stack of any scene shows.

No reference distance, so no key figure: per step the depth, intensity and
validity maps, the per-pixel temporal noise and, when the scene is planar,
the plane's distance, tilt and residual RMS (metrics/capture.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from labctl.evaluation.sections import CaptureRow
from labctl.run.store import StepRecord
from metrics.capture import CaptureSummary, summarize_capture


@dataclass(frozen=True)
class CaptureResult:
    step_id: str
    summary: CaptureSummary


def evaluate_captures(steps: Sequence[StepRecord], progress: Callable[[str], None]) -> list[CaptureResult]:
    """The summary of every capture step."""
    results = []
    for step in steps:
        progress(f"{step.step_id} capture")
        results.append(CaptureResult(step.step_id, summarize_capture(step.read("x"), step.read("y"), step.read("z"),
                                                                     step.read("intensity"))))
    return results


def capture_table(results: Sequence[CaptureResult]) -> list[CaptureRow]:
    """One row per capture step (report table and ``capture`` of keyfigures.json)."""
    rows: list[CaptureRow] = []
    for r in results:
        s, plane = r.summary, r.summary.plane
        rows.append({
            "step": r.step_id, "frames": s.frames, "valid_fraction": s.valid_fraction,
            "depth_median_mm": s.depth_median_mm, "depth_q05_mm": s.depth_q05_mm, "depth_q95_mm": s.depth_q95_mm,
            "temporal_noise_median_mm": s.temporal_noise_median_mm,
            "temporal_noise_q90_mm": s.temporal_noise_q90_mm,
            "planar": plane.planar if plane else False,
            "plane_inlier_fraction": plane.inlier_fraction if plane else math.nan,
            "plane_distance_on_axis_mm": plane.distance_on_axis_mm if plane and plane.planar else math.nan,
            "plane_tilt_about_x_deg": plane.tilt_about_x_deg if plane and plane.planar else math.nan,
            "plane_tilt_about_y_deg": plane.tilt_about_y_deg if plane and plane.planar else math.nan,
            "plane_rms_mm": plane.rms_mm if plane and plane.planar else math.nan,
        })
    return rows
