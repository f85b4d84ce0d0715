"""The console never holds up the recording: frames go to a bounded queue, dropped while it is full."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import labctl.console.state as console_state
from drivers.protocols import Frame, RobotPose
from labctl.console.state import QUEUE_SIZE, ConsoleState
from labctl.run.operator import RemoteAnswers
from labctl.run.planning import PlannedStep
from procedures.steps import Step


def wall_frame(k: int) -> Frame:
    """A 48 x 64 frame of a flat wall at 2 m."""
    z = np.full((48, 64), 2000.0, dtype=np.float32)
    return Frame(x=z * 0, y=z * 0, z=z, intensity=z / 2000, confidence=np.ones_like(z), timestamp=float(k))


def test_frames_are_dropped_not_waited_for_while_the_encoder_is_busy(monkeypatch: pytest.MonkeyPatch) -> None:
    encoding, release = threading.Event(), threading.Event()
    real_png = console_state.to_png

    def stuck_png(*args, **kwargs) -> bytes:
        encoding.set()
        assert release.wait(60), "the test never released the encoder"
        return real_png(*args, **kwargs)

    monkeypatch.setattr(console_state, "to_png", stuck_png)
    monkeypatch.setattr(console_state, "RECORDED_INTERVAL_S", 0.0)
    remote = RemoteAnswers()
    state = ConsoleState(remote)
    try:
        state.started([], [], lambda _: None)
        state.step(PlannedStep(Step(0, "depth_sweep", "wall", 100), 2000.0, 0.0, 10.0), 10.0)
        state.frame("00000_depth_sweep", 0, wall_frame(0), 10.0)
        assert encoding.wait(60)  # the encoder took the first frame and hangs in it
        for k in range(1, 20):  # each returns at once although nothing is encoded
            state.frame("00000_depth_sweep", k, wall_frame(k), 10.0)
        assert state.dropped == 19 - QUEUE_SIZE
        assert state.snapshot()["frames_done"] == 20
        release.set()
    finally:
        release.set()
        state.close()
        remote.close()
    png = state.png("depth")
    assert png is not None and png.startswith(b"\x89PNG")
    assert state.snapshot()["image"]["label"] == f"00000_depth_sweep frame {QUEUE_SIZE + 1}"


def test_the_robot_is_followed_while_it_moves_and_shown_as_read_back_after() -> None:
    remote = RemoteAnswers()
    state = ConsoleState(remote)
    try:
        state.robot_pose(RobotPose(4.5, 700.0, (1.0, 2.0, 3.0)))
        readings = state.snapshot()["readings"]
        assert (readings["robot_angle_deg"], readings["robot_moving"], readings["robot_tcp_mm"]) == (4.5, True, [1.0, 2.0, 3.0])
        state.readings(1999.5, RobotPose(10.0, 700.0), 250.0)
        readings = state.snapshot()["readings"]
        assert readings == {"laser_mm": 1999.5, "robot_angle_deg": 10.0, "robot_radius_mm": 700.0, "robot_tcp_mm": None,
                            "robot_moving": False, "stage_mm": 250.0}
    finally:
        state.close()
        remote.close()
