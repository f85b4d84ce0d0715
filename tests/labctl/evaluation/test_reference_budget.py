"""The reference chain's Type B components (JCGM 100:2008, 4.3) from the laser meter's stated figures.

Dimetix DAN-10-150: accuracy +-1 mm, a bound taken as rectangular (GUM 4.3.7: 1 / sqrt(3) = 0.5774 mm);
repeatability 0.3 mm at 2 sigma (GUM 4.3.3: 0.15 mm per reading, 0.15 / sqrt(5) = 0.0671 mm on the mean of 5);
the depth origin's assumed +-1 mm tolerance, rectangular like the accuracy.
"""

from __future__ import annotations

import pytest

from labctl.evaluation.uncertainty import absolute_reference, calibrated_reference
from metrics.uncertainty import Component

LASER_STEP = {"reference_source": "laser", "laser_readings_mm": [2000.1, 2000.3, 2000.2, 2000.0, 2000.4],
              "laser_distance_mm": 2000.2, "absolute_reference_mm": 1958.2}


def test_the_absolute_reference_takes_the_laser_accuracy_repeatability_and_depth_origin_tolerance():
    values = [c.value for c in absolute_reference(LASER_STEP)]
    assert values == pytest.approx([0.57735, 0.067082, 0.57735], abs=1e-5)


def test_without_an_absolute_reference_or_a_laser_reading_there_is_no_budget():
    assert absolute_reference({**LASER_STEP, "absolute_reference_mm": float("nan")}) == ()
    assert absolute_reference({"reference_source": "stage", "absolute_reference_mm": float("nan")}) == ()


def test_the_calibrated_reference_adds_the_offset_calibration_and_leaves_out_the_laser_accuracy():
    """A bias the laser has at the step and at the offset calibration alike cancels in laser + offset."""
    calibration = (Component("offset calibration", 0.05),)
    values = [c.value for c in calibrated_reference(LASER_STEP, calibration)]
    assert values == pytest.approx([0.067082, 0.05], abs=1e-6)


def test_a_reference_of_unknown_uncertainty_gives_no_budget():
    """The stage's nominal distance, or an offset given in the campaign (no offset calibration)."""
    assert calibrated_reference({"reference_source": "stage", "reference_distance_mm": 2000.0},
                                (Component("offset calibration", 0.05),)) == ()
    assert calibrated_reference(LASER_STEP, ()) == ()
