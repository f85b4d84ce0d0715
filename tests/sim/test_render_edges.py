"""The renderer's edge pixels: those whose footprint an edge crosses get supersampled (sim/render.py)."""

import numpy as np
import pytest

from metrics.optics import Pinhole
from sim.geometry import Pose
from sim.optics import CameraOptics
from sim.render import render
from sim.scenes.base import PlaneSurface, Scene, uniform
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
