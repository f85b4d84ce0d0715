"""Suitability checks on known inputs (Thesis 2024, Table 3-1; ISO/IEC 39794-5 Annex D; depth judgements)."""

import pytest

from labctl.evaluation.suitability import (
    FACE_PRECISION,
    FACE_TRUENESS,
    STORIES,
    face_depth_values,
    suitability,
)

GOOD = {
    "radial_distortion_cloud_w_pct": -2.0, "radial_distortion_cloud_h_pct": 2.5,
    "radial_distortion_intensity_w_pct": 3.0, "radial_distortion_intensity_h_pct": 1.0,
    "ied_pixels_at_hyperfocal": 95.0, "pixel_aspect_distortion_pct": 1.5,
    FACE_PRECISION: 0.6, FACE_TRUENESS: 1.5,
}


def verdicts(values):
    return {k: v.verdict for k, v in suitability(values).stories.items()}


def test_all_requirements_met():
    v = verdicts(GOOD)
    assert v["3d_face_recognition_1_to_n"] == v["3d_face_recognition_1_to_1"] == v["pad_makeup_nir"] == "pass"
    assert v["pad_light"] == v["pad_makeup_rgb"] == "pass"
    assert v["3d_support"] == "no_numeric_requirement"
    story = suitability(GOOD).stories["3d_face_recognition_1_to_n"]
    assert story.summary == "meets all 5 requirements"


def test_blaze_like_camera_fails_on_ied_only():
    """A blaze-101 at 400 mm: 75.5 px at the image centre, below the 90 px of ISO/IEC 39794-5."""
    result = suitability(dict(GOOD, ied_pixels_at_hyperfocal=75.5)).stories["3d_face_recognition_1_to_n"]
    assert result.verdict == "fail"
    failed = [c.requirement for c in result.checks if c.status == "fail"]
    assert len(failed) == 1 and failed[0].startswith("inter-eye distance >= 90 px")
    assert result.summary.startswith("fails inter-eye distance >= 90 px") and "75.5" in result.summary


def test_depth_precision_decides_where_the_image_figures_pass():
    """A noisy camera passes every 2D requirement but fails recognition (1 mm) and the landmark check
    (2 mm) on depth; the liveness check (5 mm) still passes."""
    v = verdicts(dict(GOOD, **{FACE_PRECISION: 2.8}))
    assert v["3d_face_recognition_1_to_n"] == v["3d_face_recognition_1_to_1"] == "fail"
    assert v["pad_makeup_nir"] == v["pad_makeup_rgb"] == "fail"
    assert v["pad_light"] == "pass"
    story = suitability(dict(GOOD, **{FACE_PRECISION: 2.8})).stories["3d_face_recognition_1_to_1"]
    assert story.summary == "fails depth precision <= 1 mm on the face: 2.8"
    assert verdicts(dict(GOOD, **{FACE_TRUENESS: -2.5}))["3d_face_recognition_1_to_1"] == "fail"  # |trueness|
    assert verdicts(dict(GOOD, **{FACE_TRUENESS: 2.5}))["pad_makeup_nir"] == "pass"  # no trueness limit there


def test_depth_limits_are_marked_as_judgements_with_sources():
    for story in suitability(GOOD).stories.values():
        for check in story.checks:
            assert check.source
            is_depth = "depth" in check.requirement
            assert check.judgement == is_depth and check.source.startswith("judgement") == is_depth


def test_1_to_1_tolerates_more_distortion_than_1_to_n():
    """flexx2-like: 6 % cloud distortion fails 1:N (5 %) but passes 1:1 (7 %)."""
    v = verdicts(dict(GOOD, radial_distortion_cloud_h_pct=6.0))
    assert v["3d_face_recognition_1_to_n"] == "fail" and v["3d_face_recognition_1_to_1"] == "pass"


def test_d455_like_pixel_aspect_fails():
    v = verdicts(dict(GOOD, pixel_aspect_distortion_pct=10.2))
    assert v["pad_makeup_nir"] == "fail"


def test_missing_figures_are_not_evaluated_not_passed():
    result = suitability({"pixel_aspect_distortion_pct": 1.5}).stories
    assert result["3d_face_recognition_1_to_n"].verdict == "not_evaluated"
    assert "ied_pixels_at_hyperfocal" in result["3d_face_recognition_1_to_n"].summary
    assert "fail" not in {s.verdict for s in result.values()}


def test_a_failing_check_wins_over_missing_ones():
    assert verdicts({"pixel_aspect_distortion_pct": 12.0})["3d_face_recognition_1_to_1"] == "fail"


def test_every_story_is_reported_with_a_one_line_summary():
    stories = suitability(GOOD).stories
    assert set(stories) == set(STORIES)
    assert all(s.summary and "\n" not in s.summary for s in stories.values())


def test_face_depth_comes_from_the_first_wall_step_at_or_beyond_the_face():
    rows = [{"reference_mm": r, "precision_q90_mm": p, "trueness_q90_mm": t}
            for r, p, t in ((500.0, 0.4, 1.0), (1000.0, 0.9, 1.2), (300.0, 0.2, 0.8))]
    face = face_depth_values({"hyperfocal_distance_mm": 400.0}, rows)
    assert face == pytest.approx({"face_distance_mm": 400.0, "face_wall_step_mm": 500.0, FACE_PRECISION: 0.4,
                                  FACE_TRUENESS: 1.0})
    assert face_depth_values({"hyperfocal_distance_mm": 1200.0}, rows) == {}
    blind = [{"reference_mm": 450.0, "precision_q90_mm": None, "trueness_q90_mm": None}, *rows]  # below min range
    assert face_depth_values({"hyperfocal_distance_mm": 400.0}, blind)["face_wall_step_mm"] == 500.0
    assert face_depth_values({"hyperfocal_distance_mm": None}, rows) == {}
    requirement = next(c.requirement for c in suitability({**GOOD, **face}).stories["pad_light"].checks)
    assert requirement.endswith("(wall at 500 mm, face at 400 mm)")


def test_a_limit_within_the_expanded_uncertainty_is_marginal():
    """Guard bands of width U (JCGM 106:2012, clause 8; ISO 14253-1:2017): 4.9 +- 0.3 % against the 5 % limit
    neither passes nor fails; 4.5 +- 0.3 passes, 5.4 +- 0.3 fails; an IED of 88 +- 4 px against 90 px, below the
    limit but by less than U, is marginal too, not a fail."""
    near = dict(GOOD, radial_distortion_cloud_w_pct=-4.9)
    story = suitability(near, {"radial_distortion_cloud_w_pct": 0.3}).stories["3d_face_recognition_1_to_n"]
    assert story.verdict == "marginal"
    check = next(c for c in story.checks if c.requirement.startswith("radial distortion"))
    assert check.status == "marginal" and check.uncertainties["radial_distortion_cloud_w_pct"] == 0.3
    assert check.uncertainties["radial_distortion_cloud_h_pct"] is None
    assert story.summary == ("marginal (the limit lies within the expanded uncertainty): radial distortion <= 5 %: "
                             "-4.9 +- 0.3, 2.5")
    assert suitability(near, {"radial_distortion_cloud_w_pct": 0.3}).stories["3d_face_recognition_1_to_1"].verdict == "pass"
    assert verdicts(dict(GOOD, radial_distortion_cloud_w_pct=4.5)) == {
        k: v.verdict for k, v in suitability(dict(GOOD, radial_distortion_cloud_w_pct=4.5),
                                             {"radial_distortion_cloud_w_pct": 0.3}).stories.items()}
    beyond = suitability(dict(GOOD, radial_distortion_cloud_w_pct=5.4), {"radial_distortion_cloud_w_pct": 0.3})
    assert beyond.stories["3d_face_recognition_1_to_n"].verdict == "fail"
    ied = suitability(dict(GOOD, ied_pixels_at_hyperfocal=88.0), {"ied_pixels_at_hyperfocal": 4.0}).stories
    assert ied["3d_face_recognition_1_to_n"].verdict == ied["pad_makeup_nir"].verdict == "marginal"
    assert verdicts(dict(GOOD, ied_pixels_at_hyperfocal=88.0))["3d_face_recognition_1_to_n"] == "fail"  # no U


def test_fail_and_missing_figures_outrank_marginal():
    """A story with a failing check fails, one with a missing figure is not evaluated, even where another check
    is marginal."""
    u = {FACE_PRECISION: 0.2}
    assert suitability(dict(GOOD, **{FACE_PRECISION: 0.95, FACE_TRUENESS: 2.5}), u).stories[
        "3d_face_recognition_1_to_1"].verdict == "fail"
    missing = {k: v for k, v in GOOD.items() if k != "ied_pixels_at_hyperfocal"}
    assert suitability(dict(missing, **{FACE_PRECISION: 0.95}), u).stories[
        "3d_face_recognition_1_to_1"].verdict == "not_evaluated"
    assert suitability(dict(GOOD, **{FACE_PRECISION: 0.95}), u).stories["3d_face_recognition_1_to_1"].verdict == "marginal"
