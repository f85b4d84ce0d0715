"""The analytic face mask has a face's proportions, is smooth, and offers many surface angles."""

import numpy as np
import pytest

from sim.face_mask import EYE_CENTRES_MM, NOSE_TIP_MM, angle_histogram, face_height, face_normals


def grid(x0, x1, y0, y1, step):
    return np.meshgrid(np.arange(x0, x1 + step / 2, step), np.arange(y0, y1 + step / 2, step))


def test_outline_is_an_ellipse_150_wide_and_210_high():
    x, y = grid(-80, 80, -110, 110, 0.25)
    h, valid = face_height(x, y)
    xs, ys = x[valid], y[valid]
    assert xs.max() - xs.min() == pytest.approx(150.0, abs=0.6)
    assert ys.max() - ys.min() == pytest.approx(210.0, abs=0.6)
    assert not face_height(np.array(60.0), np.array(90.0))[1]  # (60/75)^2 + (90/105)^2 > 1
    assert np.all(h[~valid] == 0.0)
    assert np.all(np.isfinite(h)) and np.all(h[valid] >= 0.0)


def test_height_vanishes_at_the_rim():
    a = np.linspace(0, 2 * np.pi, 720)
    h, valid = face_height(0.999 * 75 * np.cos(a), 0.999 * 105 * np.sin(a))
    assert np.all(valid) and np.all(h < 0.01)


def test_broadcasting_and_left_right_symmetry():
    x = np.linspace(-70, 70, 29)
    y = np.linspace(-100, 100, 41)
    h, valid = face_height(x[None, :], y[:, None])
    assert h.shape == valid.shape == (41, 29)
    assert np.allclose(h, h[:, ::-1])


def test_nose_tip_is_the_highest_point_at_30_to_35_mm():
    x, y = grid(-75, 75, -105, 105, 0.2)
    h, _ = face_height(x, y)
    i = np.unravel_index(np.argmax(h), h.shape)
    assert 30.0 <= h[i] <= 35.0
    assert np.hypot(x[i] - NOSE_TIP_MM[0], y[i] - NOSE_TIP_MM[1]) < 1.0


def test_eye_sockets_are_62_5_mm_apart_and_deeper_than_their_surroundings():
    (lx, ly), (rx, ry) = EYE_CENTRES_MM
    assert rx - lx == pytest.approx(62.5) and ly == ry
    minima = []
    for cx, cy in EYE_CENTRES_MM:
        x, y = grid(cx - 10, cx + 10, cy - 10, cy + 10, 0.1)
        h, _ = face_height(x, y)
        i = np.unravel_index(np.argmin(h), h.shape)
        minima.append((x[i], y[i]))
        assert np.hypot(x[i] - cx, y[i] - cy) < 1.5
        a = np.linspace(0, 2 * np.pi, 360, endpoint=False)
        ring, _ = face_height(cx + 15 * np.cos(a), cy + 15 * np.sin(a))
        assert ring.min() > h[i] + 5.0
        cheek, _ = face_height(np.array(np.sign(cx) * 44.0), np.array(10.0))
        assert cheek > h[i] + 10.0
    assert minima[1][0] - minima[0][0] == pytest.approx(62.5, abs=2.0)


def test_first_derivatives_are_continuous():
    """Gradient jumps between neighbouring samples halve with the spacing (C1), also across the rim."""

    def max_gradient_jump(step):
        x, y = grid(-78, 78, -108, 108, step)
        e = 1e-4
        gx = (face_height(x + e, y)[0] - face_height(x - e, y)[0]) / (2 * e)
        gy = (face_height(x, y + e)[0] - face_height(x, y - e)[0]) / (2 * e)
        return max(np.abs(np.diff(g, axis=k)).max() for g in (gx, gy) for k in (0, 1))

    coarse, fine = max_gradient_jump(0.4), max_gradient_jump(0.2)
    assert coarse < 0.5
    assert fine / coarse == pytest.approx(0.5, abs=0.1)


def test_normals_are_unit_and_face_the_camera():
    x, y = grid(-74, 74, -104, 104, 1.0)
    inside = face_height(x, y)[1]
    n = face_normals(x[inside], y[inside])
    assert n.shape == (3, inside.sum())
    assert np.allclose(np.linalg.norm(n, axis=0), 1.0)
    assert np.all(n[2] < 0)  # z points away from the camera
    assert np.allclose(face_normals(*NOSE_TIP_MM), [0, 0, -1], atol=0.05)
    side = face_normals(np.array(70.0), np.array(0.0))  # right edge of the face: normal leans right
    assert side[0] > 0.3
    assert np.allclose(face_normals(x[inside], y[inside], step_mm=0.001), n, atol=1e-4)


def test_angle_histogram_has_substantial_mass_from_30_to_75_deg():
    """Fig. 5-13: a face offers many angles, many near 40 and 70 deg.

    The model (33.6 mm of relief) has about 37 % of its projected area and
    47 % of its surface area between 30 and 75 deg, and none above 68 deg.
    """
    edges, fraction = angle_histogram()
    centres = (edges[:-1] + edges[1:]) / 2
    assert edges[0] == 0.0 and edges[-1] == 90.0
    assert fraction.sum() == pytest.approx(1.0)
    band = (centres > 30) & (centres < 75)
    assert fraction[band].sum() > 0.33
    assert fraction[(centres > 35) & (centres < 45)].sum() > 0.08
    assert fraction[(centres > 55) & (centres < 70)].sum() > 0.08
    assert fraction[centres > 75].sum() == 0.0
    _, per_surface = angle_histogram(per_surface_area=True)
    assert per_surface[band].sum() > fraction[band].sum() + 0.05
