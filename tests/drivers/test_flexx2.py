"""pmd flexx2 backend: roypy (pmd Royale) is not on PyPI and not installed here, so the tests cover
the missing-SDK report and the conversion of Royale's point array into a frame."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from drivers.camera.flexx2 import Flexx2Camera, frame_from_points
from drivers.errors import MissingSDKError


@pytest.mark.skipif(importlib.util.find_spec("roypy") is not None, reason="roypy is installed here")
@pytest.mark.parametrize("playback", [None, "recording.rrf"])
def test_missing_roypy_says_where_it_comes_from(playback: str | None) -> None:
    with pytest.raises(MissingSDKError) as caught:
        Flexx2Camera(playback=playback).connect()
    message = str(caught.value)
    assert "'roypy' is missing" in message and "Royale SDK" in message and "not on PyPI" in message
    assert "PYTHONPATH" in message


def test_points_become_a_frame_in_mm() -> None:
    """Royale's columns: x, y, z (m), noise, gray value, depth confidence (0 = invalid)."""
    points = np.zeros((2, 3, 6), np.float32)
    points[..., 0], points[..., 1], points[..., 2] = 0.1, -0.05, 1.25
    points[..., 4], points[..., 5] = 321.0, 255.0
    points[1, 2, 5] = 0.0
    frame = frame_from_points(points, timestamp_us=2_500_000)
    assert (frame.x[0, 0], frame.y[0, 0], frame.z[0, 0]) == pytest.approx((100.0, -50.0, 1250.0))
    assert np.isnan([frame.x[1, 2], frame.y[1, 2], frame.z[1, 2]]).all()
    assert frame.intensity[0, 0] == 321.0 and frame.confidence.dtype == np.uint16 and frame.confidence[1, 2] == 0
    assert frame.timestamp == 2.5 and frame.z.dtype == np.float32
