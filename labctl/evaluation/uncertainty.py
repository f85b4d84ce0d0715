"""The reference chain's share of the key figures' uncertainty budgets (docs/keyfigures.md, Uncertainty).

Type B components (GUM 4.3) from what the lab's instruments state, in mm of the reference:

* the offset calibration (``offset = camera - laser`` at 2000 mm): the laser's repeatability on its readings and
  the camera's mean depth over the central 10 % x 10 %, whose Type A uncertainty (GUM 4.2.3) is s / sqrt(N) of
  that region's mean over the N frames;
* the laser meter's repeatability (``REPEATABILITY_2SIGMA_MM`` at 2 sigma, GUM 4.3.3) on the mean of a step's
  n readings: sigma / sqrt(n);
* the laser meter's accuracy (+-``ACCURACY_MM``, a bound: rectangular, GUM 4.3.7), only where the reference is
  absolute: against the offset-calibrated reference (``laser + offset``, docs/campaign.md) a bias the meter has
  at the step and at the offset calibration alike cancels;
* the tolerance of ``devices.camera.depth_origin_offset_mm`` (``DEPTH_ORIGIN_TOLERANCE_MM``, rectangular), for the
  figures measured against the absolute reference;
* the checkerboard's tile size (``TILE_TOLERANCE_MM``, rectangular), the reference of the x/y trueness and
  accuracy;
* the camera's field of view (``FOV_TOLERANCE_DEG`` on each of its two angles, rectangular), from which the
  figures that count pixels per angle take the sensor's angular resolution (pixel aspect, intensity resolution,
  inter-eye distance), through each figure's sensitivity to the angle (:func:`fov_components`).

The reference's uncertainty is not estimated (the budget is empty, the figure's uncertainty null) where the
reference is the stage's nominal distance or the offset was given in the campaign instead of calibrated.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from drivers.laser.dimetix import ACCURACY_MM, REPEATABILITY_2SIGMA_MM
from labctl.run.store import StepRecord
from metrics.stack import central_roi
from metrics.uncertainty import Component, from_multiple, rectangular, standard_error_of_mean

#: assumed tolerance (+-, mm) of the campaign's depth_origin_offset_mm: the vendors state the depth origin to
#: about a millimetre and the campaign gives no tolerance of its own
DEPTH_ORIGIN_TOLERANCE_MM = 1.0
#: assumed tolerance (+-, mm) of a checkerboard tile against the campaign's tile_mm: the campaign states none
TILE_TOLERANCE_MM = 0.1
#: assumed tolerance (+-, deg) of each angle of the camera's field of view (``/camera`` ``fov_deg``): datasheets
#: state the FOV in whole degrees and no tolerance, so its last digit is the least it is known to (GUM F.2.2.1)
FOV_TOLERANCE_DEG = 0.5
#: step (deg) of the central differences that give a figure's sensitivity to a FOV angle (GUM 5.1.3)
FOV_STEP_DEG = 0.01


def laser_readings(attrs: Mapping[str, Any]) -> int:
    """How many laser readings a step's ``laser_distance_mm`` is the mean of (0 without a laser reading)."""
    if attrs.get("reference_source") != "laser":
        return 0
    return len(attrs.get("laser_readings_mm", ()))


def _repeatability(n: int) -> float:
    """Standard uncertainty (mm) of the mean of ``n`` laser readings from the meter's repeatability."""
    return from_multiple(REPEATABILITY_2SIGMA_MM, 2.0) / math.sqrt(n)


def laser_step_uncertainty(attrs: Mapping[str, Any]) -> float:
    """Standard uncertainty (mm) a laser-referenced step's reference has of its own, the laser's repeatability on
    the mean of its readings (0 without laser readings): what differs from step to step, where the offset
    calibration's components are the same for every step of the run."""
    n = laser_readings(attrs)
    return _repeatability(n) if n else 0.0


def offset_calibration(step: StepRecord) -> tuple[Component, ...]:
    """The components (mm) of the camera-laser offset an ``offset_calibration`` step measured: the laser
    repeatability of its readings and the camera's mean depth over the central 10 % x 10 % (s / sqrt(N) of the
    region's per-frame means); empty (not estimated) without laser readings."""
    n = laser_readings(step.attrs)
    if n == 0:
        return ()
    z = step.group["z"]
    rows, cols = central_roi(*z.shape[1:])
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a frame without valid depth in the region: NaN
        means = np.nanmean(np.asarray(z[:, rows, cols], dtype=np.float64), axis=(1, 2))
    return (Component(f"offset calibration: laser repeatability, mean of {n} readings", _repeatability(n)),
            Component(f"offset calibration: camera's mean depth over {len(means)} frames (Type A)",
                      standard_error_of_mean(means)))


def calibrated_reference(step: Mapping[str, Any], calibration: tuple[Component, ...]) -> tuple[Component, ...]:
    """The components (mm) of a step's offset-calibrated reference ``laser + offset``: the laser repeatability of
    the step's readings and the ``calibration``'s components (:func:`offset_calibration`); empty (not
    estimated) without a laser reading at the step or without an offset calibration."""
    n = laser_readings(step)
    if n == 0 or not calibration:
        return ()
    return (Component(f"reference: laser repeatability, mean of {n} readings", _repeatability(n)), *calibration)


def absolute_reference(step: Mapping[str, Any]) -> tuple[Component, ...]:
    """The components (mm) of a step's absolute reference ``laser - depth_origin_offset_mm``: the laser's
    accuracy and repeatability and the depth origin's tolerance; empty without an absolute reference."""
    n = laser_readings(step)
    if n == 0 or not math.isfinite(float(step.get("absolute_reference_mm", math.nan))):
        return ()
    return (Component("reference: laser accuracy (rectangular)", rectangular(ACCURACY_MM)),
            Component(f"reference: laser repeatability, mean of {n} readings", _repeatability(n)),
            Component("depth origin offset tolerance (assumed, rectangular)", rectangular(DEPTH_ORIGIN_TOLERANCE_MM)))


def scaled(components: tuple[Component, ...], factor: float) -> tuple[Component, ...]:
    """The components each times ``factor``: a sensitivity coefficient (GUM 5.1.3), or a change of unit (mm to
    % of a distance: 100 / distance)."""
    return tuple(Component(c.name, c.value * factor) for c in components)


def tile_size(tile_mm: float) -> Component:
    """The component (mm) of a checkerboard tile of nominal ``tile_mm``: the assumed tolerance
    ``TILE_TOLERANCE_MM`` as a bound, rectangular (GUM 4.3.7); the caller scales it by the figure's sensitivity."""
    return Component(f"tile size {tile_mm:g} mm: tolerance (assumed, rectangular)", rectangular(TILE_TOLERANCE_MM))


def fov_components(figure: Callable[[float, float], float], fov_deg: tuple[float, float]) -> tuple[Component, ...]:
    """The components of a figure computed from the field of view ``fov_deg`` (horizontal, vertical) by
    ``figure(fov_h, fov_v)``: each angle's assumed tolerance ``FOV_TOLERANCE_DEG`` as a bound, rectangular (GUM
    4.3.7), times the figure's sensitivity to that angle by central differences of ``FOV_STEP_DEG`` (GUM 5.1.3);
    an angle the figure does not depend on gives no component."""
    h, v = fov_deg
    u = rectangular(FOV_TOLERANCE_DEG)
    out = []
    for axis, plus, minus in (("horizontal", (h + FOV_STEP_DEG, v), (h - FOV_STEP_DEG, v)),
                              ("vertical", (h, v + FOV_STEP_DEG), (h, v - FOV_STEP_DEG))):
        sensitivity = (figure(*plus) - figure(*minus)) / (2 * FOV_STEP_DEG)
        if sensitivity != 0.0 and math.isfinite(sensitivity):
            out.append(Component(f"FOV {axis}: +-{FOV_TOLERANCE_DEG:g} deg (assumed, rectangular)",
                                 u * abs(sensitivity)))
    return tuple(out)
