"""Geometry of the measurement circle: known poses, round trips, configuration errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.robot import MeasurementCircle

CENTER = (100.0, -200.0, 300.0)


def looking_along(direction: list[float]) -> np.ndarray:
    """Rotation vector of a TCP whose z axis points along ``direction`` (its y axis up the base z)."""
    z = np.asarray(direction, float) / np.linalg.norm(direction)
    y = np.array([0.0, 0.0, 1.0])
    x = np.cross(y, z)
    return Rotation.from_matrix(np.column_stack([x, y, z])).as_rotvec()


def circle(radius: float = 500.0) -> MeasurementCircle:
    zero = [CENTER[0] + radius, CENTER[1], CENTER[2], *looking_along([-1.0, 0.0, 0.0])]
    return MeasurementCircle(CENTER, (0.0, 0.0, 1.0), zero)


def optical_axis(pose: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(pose[3:]).apply([0.0, 0.0, 1.0])


@pytest.mark.parametrize(("angle", "expected_xy"), [(0.0, (500.0, 0.0)), (90.0, (0.0, 500.0)), (-90.0, (0.0, -500.0)),
                                                    (180.0, (-500.0, 0.0)), (30.0, (433.0127, 250.0))])
def test_positions_on_the_circle_follow_the_right_hand_rule(angle: float, expected_xy: tuple[float, float]) -> None:
    pose = circle().pose(angle, 500.0)
    assert pose[:3] - np.array(CENTER) == pytest.approx([*expected_xy, 0.0], abs=1e-3)


@pytest.mark.parametrize("angle", [-75.0, -10.0, 0.0, 45.0, 89.0])
@pytest.mark.parametrize("radius", [250.0, 500.0, 850.0])
def test_the_camera_always_looks_at_the_centre(angle: float, radius: float) -> None:
    pose = circle().pose(angle, radius)
    to_center = np.array(CENTER) - pose[:3]
    assert np.linalg.norm(to_center) == pytest.approx(radius)
    assert optical_axis(pose) == pytest.approx(to_center / radius, abs=1e-9)


def test_camera_roll_is_kept_around_the_circle() -> None:
    """The TCP y axis stays parallel to the rotation axis (no roll about the optical axis)."""
    for angle in (-60.0, 0.0, 60.0):
        y_axis = Rotation.from_rotvec(circle().pose(angle, 400.0)[3:]).apply([0.0, 1.0, 0.0])
        assert y_axis == pytest.approx([0.0, 0.0, 1.0], abs=1e-9)


def test_locate_inverts_pose() -> None:
    geometry = circle()
    for angle, radius in [(-80.0, 300.0), (0.0, 500.0), (37.5, 812.0)]:
        where = geometry.locate(geometry.pose(angle, radius))
        assert (where.angle_deg, where.radius_mm) == pytest.approx((angle, radius))
        assert where.off_plane_mm == pytest.approx(0.0, abs=1e-9)
        assert where.aim_error_deg == pytest.approx(0.0, abs=1e-6)


def test_locate_reports_how_far_a_pose_is_off() -> None:
    geometry = circle()
    pose = geometry.pose(20.0, 500.0)
    pose[2] += 7.0
    pose[3:] = (Rotation.from_rotvec([0.0, 0.0, math.radians(3.0)]) * Rotation.from_rotvec(pose[3:])).as_rotvec()
    where = geometry.locate(pose)
    assert where.off_plane_mm == pytest.approx(7.0)
    assert where.aim_error_deg == pytest.approx(3.0)


def test_a_tilted_axis() -> None:
    """A circle in a vertical plane: rotation about the base y axis."""
    zero = [CENTER[0], CENTER[1], CENTER[2] + 400.0, *Rotation.from_rotvec([math.pi, 0.0, 0.0]).as_rotvec()]
    geometry = MeasurementCircle(CENTER, (0.0, 2.0, 0.0), zero)
    pose = geometry.pose(90.0, 400.0)
    assert pose[:3] - np.array(CENTER) == pytest.approx([400.0, 0.0, 0.0], abs=1e-9)
    assert optical_axis(pose) == pytest.approx([-1.0, 0.0, 0.0], abs=1e-9)


def test_arc_waypoints() -> None:
    geometry = circle()
    waypoints = geometry.arc(0.0, 12.0, 500.0, 5.0)
    assert len(waypoints) == 3
    assert [geometry.locate(p).angle_deg for p in waypoints] == pytest.approx([4.0, 8.0, 12.0])
    assert len(geometry.arc(10.0, -10.0, 500.0, 5.0)) == 4
    with pytest.raises(ValueError, match="step_deg must be positive"):
        geometry.arc(0.0, 1.0, 500.0, 0.0)


@pytest.mark.parametrize(
    ("zero", "axis", "message"),
    [
        ([600.0, -200.0, 310.0, *looking_along([-1.0, 0.0, 0.0])], (0, 0, 1), "10.0 mm off the circle's plane"),
        ([600.0, -200.0, 300.0, *looking_along([0.0, 1.0, 0.0])], (0, 0, 1), "misses the centre by 90.0°"),
        ([100.0, -200.0, 300.0, 0.0, 0.0, 0.0], (0, 0, 1), "coincides with the circle's centre"),
        ([600.0, -200.0, 300.0, 0.0, 0.0, 0.0], (0, 0, 0), "rotation axis must be a non-zero vector"),
    ],
)
def test_inconsistent_configuration_is_refused(zero: list[float], axis: tuple[float, ...], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        MeasurementCircle(CENTER, axis, zero)
