"""Suitability checks (Thesis 2024, Ch. 3, 6.6, Table 3-1)."""

from labctl.suitability import STORIES, suitability

GOOD = {
    "radial_distortion_cloud_w_pct": -2.0, "radial_distortion_cloud_h_pct": 2.5,
    "radial_distortion_intensity_w_pct": 3.0, "radial_distortion_intensity_h_pct": 1.0,
    "ied_pixels_at_hyperfocal": 95.0, "pixel_aspect_distortion_pct": 1.5,
}


def verdicts(values):
    return {k: v["verdict"] for k, v in suitability(values)["stories"].items()}


def test_all_requirements_met():
    v = verdicts(GOOD)
    assert v["3d_face_recognition_1_to_n"] == v["3d_face_recognition_1_to_1"] == v["pad_makeup_nir"] == "pass"
    assert v["pad_light"] == "no_numeric_requirement"


def test_blaze_like_camera_fails_on_ied_only():
    """Thesis 2024, 6.6: the Blaze101 covers the IED with 88 px, below the 90 px required."""
    values = dict(GOOD, ied_pixels_at_hyperfocal=88.0)
    result = suitability(values)["stories"]["3d_face_recognition_1_to_n"]
    assert result["verdict"] == "fail"
    statuses = {c["requirement"]: c["status"] for c in result["checks"]}
    assert statuses == {"radial distortion <= 5 %": "pass", "inter-eye distance >= 90 px at the hyperfocal distance": "fail",
                        "pixel aspect ratio within +-10 %": "pass"}


def test_1_to_1_tolerates_more_distortion_than_1_to_n():
    """flexx2-like: 6 % cloud distortion fails 1:N (5 %) but passes 1:1 (7 %)."""
    v = verdicts(dict(GOOD, radial_distortion_cloud_h_pct=6.0))
    assert v["3d_face_recognition_1_to_n"] == "fail" and v["3d_face_recognition_1_to_1"] == "pass"


def test_d455_like_pixel_aspect_fails():
    v = verdicts(dict(GOOD, pixel_aspect_distortion_pct=10.2))
    assert v["pad_makeup_nir"] == "fail"


def test_missing_figures_are_not_evaluated_not_passed():
    v = verdicts({"pixel_aspect_distortion_pct": 1.5})
    assert v["3d_face_recognition_1_to_n"] == "not_evaluated"
    assert "fail" not in v.values()


def test_a_failing_check_wins_over_missing_ones():
    assert verdicts({"pixel_aspect_distortion_pct": 12.0})["3d_face_recognition_1_to_1"] == "fail"


def test_every_story_is_reported():
    assert set(suitability(GOOD)["stories"]) == set(STORIES)
