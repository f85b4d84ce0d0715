"""The captures that separate confounded effects: never one the run already holds.

The runs here are campaigns' planned steps (``labctl plan``'s schedule), so
their positions and times are those a run of the campaign would have: an
offset calibration at 2000 mm, then a wall sweep, with or without the new
sweep keys (``order``, ``return_mm``).
"""

from __future__ import annotations

import pytest

from labctl.reconcile.confounds import (
    Capture,
    Holdings,
    plan_captures,
    separating_capture,
    signal_separated,
    time_separated,
)
from labctl.run.config import parse_campaign
from labctl.run.planning import schedule
from procedures.depth_sweep import DepthSweep
from sim.effects.temperature_drift import EFFECT as DRIFT
from tests.conftest import campaign_text


def _captures(sweep: str, extra: str = "", devices: str = "") -> list[Capture]:
    text = campaign_text(extra_devices=devices, procedures=f"""
        [[procedure]]
        kind = "offset_calibration"
        distance_mm = 2000
        frames = 8

        [[procedure]]
        kind = "depth_sweep"
        start_mm = 400
        stop_mm = 1600
        step_mm = 400
        frames = 8
        {sweep}
        {extra}
        """)
    return plan_captures(schedule(parse_campaign(text)))


def test_sweep_orders_and_return():
    sweep = {"kind": "depth_sweep", "start_mm": 400, "stop_mm": 2000, "step_mm": 400}
    assert DepthSweep(**sweep).stage_distances_mm() == [400, 800, 1200, 1600, 2000]
    assert DepthSweep(**sweep, order="descending").stage_distances_mm() == [2000, 1600, 1200, 800, 400]
    assert DepthSweep(**sweep, order="interleaved").stage_distances_mm() == [400, 1200, 2000, 1600, 800]
    steps = list(DepthSweep(**sweep, order="interleaved", return_mm=1000).steps(3))
    assert [s.distance_mm for s in steps] == [400, 1200, 2000, 1600, 800, 1000]
    assert [s.step_id for s in steps][-1] == "00008_depth_sweep"


def drift_capture(captures: list[Capture], tau_s: float) -> str:
    """The drift's own capture hint, asked what ``captures`` hold."""
    assert DRIFT.observed is not None and DRIFT.observed.capture is not None
    return DRIFT.observed.capture({"tau_s": tau_s}, Holdings(captures))


def test_a_drift_hint_never_asks_for_a_repeat_the_run_already_has():
    plain = _captures("")
    returned = _captures("return_mm = 2000")
    # the plain run sees 2000 mm once: the repeat is the capture that would determine the drift
    assert "repeat the 2000 mm position later in the run" in drift_capture(plain, 17.0)
    # the returning run has 2000 mm again long after 3 x 17 s: the hint must ask for something else
    repeat = returned[-1].time_s - returned[0].time_s
    assert repeat > 3 * 17.0
    hint = drift_capture(returned, 17.0)
    assert "later in the run" not in hint
    assert "first 17 s" in hint


def test_the_separating_capture_of_drift_and_range_is_one_the_run_lacks():
    plain = _captures("")
    assert time_separated(plain) is None
    assert "return_mm = 2000" in separating_capture("temperature_drift", "range_scale", plain)
    returned = _captures("return_mm = 2000")
    assert "seen again" in time_separated(returned)
    hint = separating_capture("temperature_drift", "range_scale", returned)
    assert "return_mm" not in hint and "interleaved" in hint
    both = _captures('order = "interleaved"\nreturn_mm = 2000')
    hint = separating_capture("temperature_drift", "range_scale", both)
    assert "return_mm" not in hint and "interleaved" not in hint and "warm" in hint


def test_the_separating_capture_of_signal_and_range_is_one_the_run_lacks():
    walls = _captures("")
    assert signal_separated(walls) is None
    assert "remission" in separating_capture("intensity_related_error", "range_scale", walls)
    plates = """
        [[procedure]]
        kind = "remission_angle"
        materials = ["ptfe", "silicone"]
        angles_deg = [-20, 20, 20]
        radius_mm = 850
        frames = 4
        """
    robot = '[devices.robot]\nhost = "192.168.1.10"\nradius_max_mm = 850'
    with_plates = _captures("", extra=plates, devices=robot)
    assert "ptfe, silicone" in signal_separated(with_plates)
    hint = separating_capture("intensity_related_error", "range_scale", with_plates)
    assert "remission" not in hint and "exposure" in hint


@pytest.mark.parametrize("order", ["ascending", "descending"])
def test_a_one_way_sweep_does_not_tell_time_from_distance(order):
    assert time_separated(_captures(f'order = "{order}"')) is None
