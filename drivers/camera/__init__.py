"""3D camera adapters (:class:`~drivers.protocols.DepthCamera`); each imports its SDK when it connects.

=========== ================================================ =====================
backend     SDK                                              recordings
=========== ================================================ =====================
realsense   pyrealsense2 (librealsense)                      ``.bag``, ``.db3``
blaze       pypylon or harvesters + Basler's blaze producer  --
amt100      harvesters + Schmersal's GenTL producer          --
flexx2      roypy (pmd Royale SDK)                           ``.rrf``
=========== ================================================ =====================
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from drivers.camera.amt100 import amt100_camera
from drivers.camera.blaze import blaze_camera
from drivers.camera.flexx2 import Flexx2Camera
from drivers.camera.realsense import RealSenseCamera
from drivers.protocols import DepthCamera

BACKENDS = ("realsense", "blaze", "amt100", "flexx2")
PLAYBACK_BACKENDS = ("realsense", "flexx2")
GENTL_BACKENDS = ("blaze", "amt100")


def open_camera(
    backend: str,
    *,
    serial: str | None = None,
    playback: str | Path | None = None,
    producers: Sequence[str | Path] | None = None,
    sdk: str = "pypylon",
    timeout_s: float = 5.0,
) -> DepthCamera:
    """The adapter for ``backend`` (not connected yet). ``playback``: a recording instead of a live
    camera (realsense, flexx2); ``producers``: GenTL ``.cti`` files (blaze with harvesters, amt100);
    ``sdk``: ``pypylon`` or ``harvesters`` (blaze). ValueError for combinations that do not exist."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown camera backend {backend!r}; expected one of {list(BACKENDS)}")
    if playback is not None and backend not in PLAYBACK_BACKENDS:
        raise ValueError(f"backend {backend!r} cannot play recordings; only {list(PLAYBACK_BACKENDS)} can")
    if producers is not None and backend not in GENTL_BACKENDS:
        raise ValueError(f"GenTL producers apply to {list(GENTL_BACKENDS)}, not to {backend!r}")
    if sdk != "pypylon" and backend != "blaze":
        raise ValueError(f"sdk applies to the blaze backend only, not to {backend!r}")
    if backend == "realsense":
        return RealSenseCamera(serial, playback, timeout_s=timeout_s)
    if backend == "blaze":
        return blaze_camera(serial, sdk=sdk, producers=producers, timeout_s=timeout_s)
    if backend == "amt100":
        return amt100_camera(serial, producers=producers, timeout_s=timeout_s)
    return Flexx2Camera(serial, playback, timeout_s=timeout_s)
