"""The renderer's edge pixels: those whose footprint an edge crosses get supersampled (sim/render.py)."""

import math

import numpy as np
import pytest

from metrics.optics import Pinhole
from sim.geometry import Pose
from sim.optics import CameraOptics
from sim.render import render
from sim.scenes.base import PlaneSurface, Scene, SphereSurface, uniform
from sim.scenes.patterns import Rect
from sim.tof import surface_properties

BOARD, WALL = 0.9, 0.5  # reflectances


def _board_before_wall() -> Scene:
    """A board 5000 x 1900 mm at 1000 mm, centred on the axis, before a wall at 2000 mm."""
    x, y = np.eye(3)[:2]
    board = PlaneSurface(np.array([0.0, 0.0, 1000.0]), x, y, uniform(BOARD), "chart_white", Rect(5000.0, 1900.0))
    wall = PlaneSurface(np.array([0.0, 0.0, 2000.0]), x, y, uniform(WALL), "wall")
    return Scene().add(board).add(wall)


def test_an_edge_between_the_outer_samples_and_the_border_is_found_on_the_border():
    """A 4 x 4 camera over 90 deg: f = 2 px, principal point 1.5 (metrics.optics.Pinhole). Pixel row 3 spans
    v = 2.5 ... 3.5 and its 2 x 2 samples lie at v = 2.75 and 3.25. The board's lower edge, y = 950 mm at
    1000 mm, appears at v = 1.5 + 2 x 0.95 = 3.4 and its upper edge at v = -0.4: a tenth of rows 0 and 3
    sees the wall, which none of their samples does. Only the ring of samples on the border finds it; the
    supersampled pixel then holds the wall's tenth (within the 16 sample rows' 1/16)."""
    scene, optics = _board_before_wall(), CameraOptics(Pinhole(4, 4, 90.0, 90.0))
    props = surface_properties(scene, {})
    inner = render(scene, Pose.at_origin(), optics, props)
    bordered = render(scene, Pose.at_origin(), optics, props, border=True)
    assert not inner.edge.any()
    np.testing.assert_array_equal(bordered.edge, np.array([[True] * 4, [False] * 4, [False] * 4, [True] * 4]))
    # each sample's passive light is its reflectance times the same cosine on either plane (frontal planes)
    wall_share = (1.0 - bordered.passive[3] / inner.passive[3]) / (1.0 - WALL / BOARD)
    np.testing.assert_allclose(wall_share, 0.1, atol=1.0 / 16)
    np.testing.assert_array_equal(bordered.passive[1:3], inner.passive[1:3])


def test_the_border_ring_finds_no_edge_where_there_is_none():
    """The board filling the view beyond its border: nothing to find."""
    scene, optics = _board_before_wall(), CameraOptics(Pinhole(4, 4, 60.0, 60.0))
    rendered = render(scene, Pose.at_origin(), optics, surface_properties(scene, {}), border=True)
    assert not rendered.edge.any()
    assert rendered.passive == pytest.approx(render(scene, Pose.at_origin(), optics,
                                                    surface_properties(scene, {})).passive)


def test_a_sphere_between_the_samples_is_found_by_the_ray_through_its_centre():
    """A 5 x 5 camera over 90 deg: f = 2.5 px, principal point 2, so the axis crosses pixel (2, 2) at its
    centre, and that pixel's 2 x 2 samples lie 0.25 px off it along each axis, 0.354 px from the centre. A dark
    sphere of 119 mm radius 1000 mm away on the axis has an image of radius f tan(asin(119 / 1000)) = 0.300 px:
    between the samples. Its pixel becomes an edge pixel, and nothing else does. Supersampled, the pixel holds the
    sphere's share of its area, s = pi 0.3^2 = 0.283 (within one of its 16 samples): its passive light
    (reflectance x cos^m) falls from the wall's by s (1 - 0.05 cos^m / 0.5), between 0.9 s and s."""
    x, y = np.eye(3)[:2]
    wall = PlaneSurface(np.array([0.0, 0.0, 2000.0]), x, y, uniform(WALL), "wall")
    sphere = SphereSurface(np.array([0.0, 0.0, 1000.0]), 119.0, uniform(0.05), "chart_black")
    optics = CameraOptics(Pinhole(5, 5, 90.0, 90.0))
    alone = Scene().add(wall)
    with_sphere = Scene().add(sphere).add(wall)
    plain = render(alone, Pose.at_origin(), optics, surface_properties(alone, {}))
    rendered = render(with_sphere, Pose.at_origin(), optics, surface_properties(with_sphere, {}))
    expected = np.zeros((5, 5), dtype=bool)
    expected[2, 2] = True
    np.testing.assert_array_equal(rendered.edge, expected)
    area = math.pi * (2.5 * math.tan(math.asin(0.119))) ** 2
    fall = 1.0 - rendered.passive[2, 2] / plain.passive[2, 2]
    assert 0.9 * (area - 1 / 16) <= fall <= area + 1 / 16
