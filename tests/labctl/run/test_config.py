"""Campaign validation: every bad field is named, nothing moves before it is checked."""

import pytest

from labctl.errors import InputError
from labctl.run.config import parse_campaign
from tests.conftest import campaign_text


def errors_of(text: str) -> str:
    with pytest.raises(InputError) as info:
        parse_campaign(text, "c.toml")
    return str(info.value)


def test_valid_campaign_plans_steps_in_order():
    campaign = parse_campaign(campaign_text())
    ids = [s.step_id for s in campaign.steps()]
    assert ids[0] == "00000_offset_calibration"
    assert ids[1:] == [f"{i:05d}_depth_sweep" for i in range(1, 6)]
    assert [s.distance_mm for s in campaign.steps()[1:]] == [1000, 1500, 2000, 2500, 3000]


def test_malformed_toml_names_the_line():
    message = errors_of("[campaign\nname = 1")
    assert "c.toml: not valid TOML" in message and "line 1" in message


def test_unknown_key_names_section_and_key():
    text = campaign_text().replace('protocol = "zaber"', 'protocol = "zaber"\nspeed = 3')
    assert "unknown key 'speed' in [devices.stage]" in errors_of(text)


def test_unknown_procedure_key_names_its_index():
    text = campaign_text().replace("step_mm = 500", "step_mm = 500\nrepeat = 2")
    assert "unknown key 'repeat' in [procedure[1]]" in errors_of(text)


def test_positions_beyond_travel_are_refused():
    text = campaign_text().replace("stop_mm = 3000", "stop_mm = 4500")
    message = errors_of(text)
    assert "procedure[1] (depth_sweep)" in message
    assert "4500" in message and "travel_mm [0, 4000]" in message


def test_distance_mapping_with_stage_offset():
    text = campaign_text().replace("travel_mm = [0, 4000]", "travel_mm = [0, 2500]\ndistance_at_zero_mm = 600")
    assert len(parse_campaign(text).steps()) == 6
    text = text.replace("start_mm = 1000", "start_mm = 500")
    assert "distance 500 mm needs stage position -100 mm" in errors_of(text)


def test_zero_frames_names_field_and_range():
    text = campaign_text().replace("frames = 8\n\n", "frames = 0\n\n", 1)
    message = errors_of(text)
    assert "procedure[0].frames" in message and "greater than or equal to 1" in message and "(got 0)" in message


def test_unknown_backend_lists_the_allowed_ones():
    message = errors_of(campaign_text(backend="kinect"))
    assert "devices.camera.backend" in message and "'realsense'" in message and "kinect" in message


def test_unknown_procedure_kind():
    text = campaign_text().replace('kind = "depth_sweep"', 'kind = "spiral"')
    assert "procedure[1].kind = 'spiral' is not available" in errors_of(text)
    text = campaign_text().replace('kind = "depth_sweep"', "kind = []")  # not a name at all: no TypeError
    assert "procedure[1].kind = [] is not available" in errors_of(text)


def test_reversed_sweep():
    text = campaign_text().replace("start_mm = 1000", "start_mm = 3500")
    assert "stop_mm (3000) must not be smaller than start_mm (3500)" in errors_of(text)


@pytest.mark.parametrize("kind", ["depth_sweep", "slanted_edge"])
def test_a_sweep_with_more_positions_than_a_stage_travel_holds_is_refused(kind):
    # 2000 mm in steps of 1e-7 mm: 2e10 positions, which planning would otherwise try to hold in memory
    text = campaign_text(procedures=f"""
    [[procedure]]
    kind = "{kind}"
    start_mm = 1000
    stop_mm = 3000
    step_mm = 1e-7
    """)
    message = errors_of(text)
    assert "step_mm = 1e-07 gives 2e+10 positions from 1000 to 3000 mm" in message
    assert "more than the 10000 a sweep may have" in message


@pytest.mark.parametrize(("angles", "expected"), [
    ("[-80, 80, 1e-6]", "angles_deg step 1e-06 gives 1.6e+08 robot poses from -80 to 80 deg, more than the 10000"),
    ("[-100, 100, 10]", "angles_deg must stay inside (-90, 90) deg, got [-100.0, 100.0, 10.0]"),
    ("[-80, 95, 5]", "angles_deg must stay inside (-90, 90) deg, got [-80.0, 95.0, 5.0]"),
])
def test_a_remission_angle_sweep_outside_the_half_circle_or_too_fine_is_refused(angles, expected):
    text = campaign_text(procedures=f"""
    [[procedure]]
    kind = "remission_angle"
    angles_deg = {angles}
    """)
    assert expected in errors_of(text)


def test_sweep_needs_offset_before_it():
    text = campaign_text(procedures="""
    [[procedure]]
    kind = "depth_sweep"
    start_mm = 1000
    stop_mm = 2000
    step_mm = 500
    frames = 4
    """)
    assert "needs the camera-laser offset" in errors_of(text)
    ok = text.replace('port = "/dev/null"', 'port = "/dev/null"\noffset_mm = -40.0')
    assert parse_campaign(ok).devices.laser.offset_mm == -40.0


def test_fault_rates_are_probabilities():
    message = errors_of(campaign_text(faults="[sim.faults]\ndropped_frame = 1.5"))
    assert "sim.faults.dropped_frame" in message


def test_several_errors_reported_together():
    text = campaign_text(backend="nope").replace("frames = 8\n\n", "frames = -1\n\n", 1)
    message = errors_of(text)
    assert "devices.camera.backend" in message and "procedure[0].frames" in message


def test_stage_checksums_are_a_zaber_option():
    text = campaign_text().replace('protocol = "zaber"', 'protocol = "grbl"\nchecksums = true')
    assert "checksums apply to Zaber stages only" in errors_of(text)
    zaber = parse_campaign(campaign_text().replace('protocol = "zaber"', 'protocol = "zaber"\nchecksums = true'))
    assert zaber.devices.stage.checksums is True


def test_depth_origin_offset_is_optional_and_a_finite_distance():
    assert parse_campaign(campaign_text()).devices.camera.depth_origin_offset_mm is None
    assert parse_campaign(campaign_text(camera="depth_origin_offset_mm = -4.5")).devices.camera.depth_origin_offset_mm \
        == -4.5
    for bad in ('"front glass"', "nan", "inf", "1e6"):
        message = errors_of(campaign_text(camera=f"depth_origin_offset_mm = {bad}"))
        assert "devices.camera.depth_origin_offset_mm" in message, bad
