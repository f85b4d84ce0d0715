"""What the console shows: a :class:`~labctl.run.observer.RunObserver` that keeps the run's latest state
for any number of browsers to poll.

The runner's thread only copies a decimated image, at most five a second, into a bounded queue (dropped
when full) and returns; a thread of its own turns the images into PNG, so the console never slows the
recording."""

from __future__ import annotations

import itertools
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.protocols import Frame, RobotPose
from labctl.console.images import Box, decimate, scaled_box, to_png
from labctl.run.observer import RunObserver
from labctl.run.operator import RemoteAnswers
from labctl.run.planning import PlannedStep
from metrics.alignment import field_slices
from metrics.depth_quality import dqt_roi
from metrics.stack import central_roi

MAX_WIDTH = 320
"""Frames are decimated to at most this width before they are queued."""
QUEUE_SIZE = 2
"""Images waiting to be encoded; a frame arriving while it is full is not shown."""
FRAME_INTERVAL_S = 0.2
"""At most one live preview frame in this time is shown (five a second, while the operator adjusts the target
between stacks)."""
RECORDED_INTERVAL_S = 1.0
"""At most one frame of a stack being recorded in this time is shown: the recording shares the cores with the
console's encoding (five a second cost the recording about 5 % of its rate on 2 cores, bench recording)."""
MESSAGES = 40
"""Log lines kept for the page."""


@dataclass
class Images:
    """A decimated depth and intensity image, the factor, and the regions to outline (full-resolution slices)."""

    z: np.ndarray
    intensity: np.ndarray
    factor: int
    regions: list[tuple[slice, slice]]
    label: str


class ConsoleState(RunObserver):
    """The run as the page shows it; thread-safe. ``remote`` receives the answers given in the browser."""

    def __init__(self, remote: RemoteAnswers) -> None:
        self.remote = remote
        self._lock = threading.Lock()
        self._plan: list[dict[str, Any]] = []
        self._current: str | None = None
        self._frames_total = 0
        self._frames_done = 0
        self._captured = 0
        self._left_s = 0.0
        self._status = "starting"
        self._prompt: dict[str, Any] | None = None
        self._prompt_ids = itertools.count(1)
        self._readings: dict[str, Any] = {"laser_mm": None, "robot_angle_deg": None, "robot_radius_mm": None,
                                          "robot_tcp_mm": None, "robot_moving": False, "stage_mm": None}
        self._alignment: dict[str, Any] | None = None
        self._messages: deque[str] = deque(maxlen=MESSAGES)
        self._stop: Callable[[str], None] | None = None
        self._stopping = False
        self._png: dict[str, bytes] = {}
        self._image_label = ""
        self._image_version = 0
        self._step_info: tuple[str, dict[str, Any]] = ("", {})
        self._queue: queue.Queue[Images | None] = queue.Queue(maxsize=QUEUE_SIZE)
        self._encoder = threading.Thread(target=self._encode, name="console-png", daemon=True)
        self._encoder.start()
        self._offered = -RECORDED_INTERVAL_S
        self.dropped = 0
        """Frames not shown because the queue was full (the recording went on regardless)."""

    # ------------------------------------------------------------------ observer (the runner's thread)
    def started(self, plan: Sequence[PlannedStep], done: Sequence[str], stop: Callable[[str], None]) -> None:
        """Keep the plan, the steps done and the way to stop the run."""
        with self._lock:
            self._plan = [{"step_id": p.step.step_id, "procedure": p.step.procedure, "target": p.step.target,
                           "frames": p.step.frames, "duration_s": p.duration_s, "prompt": p.step.prompt or "",
                           "done": p.step.step_id in done} for p in plan]
            self._frames_total = sum(p.step.frames for p in plan)
            self._frames_done = sum(p.step.frames for p in plan if p.step.step_id in done)
            self._left_s = sum(p.duration_s for p in plan if p.step.step_id not in done)
            self._stop = stop
            self._status = "running"

    def step(self, planned: PlannedStep, lab_time_left_s: float) -> None:
        """Mark the previous step done and this one current."""
        with self._lock:
            for entry in self._plan:
                if entry["step_id"] == self._current:
                    entry["done"] = True
            self._current, self._captured, self._left_s = planned.step.step_id, 0, lab_time_left_s
            self._alignment = None
            self._step_info = (planned.step.role, dict(planned.step.target_params))

    def frame(self, step_id: str, index: int, frame: Frame, lab_time_left_s: float) -> None:
        """Count the frame; queue a decimated copy unless the queue is full."""
        with self._lock:
            self._captured += 1
            self._frames_done += 1
            self._left_s = lab_time_left_s
        self._offer(frame, f"{step_id} frame {index + 1}", RECORDED_INTERVAL_S)

    def preview(self, frame: Frame, alignment: dict[str, Any] | None) -> None:
        """Show a live frame and, at the alignment step, its corner fields."""
        if alignment is not None:
            with self._lock:
                self._alignment = {**alignment, "live": True, "time": time.time()}
        self._offer(frame, "live", FRAME_INTERVAL_S)

    def readings(self, laser_mm: float | None, robot: RobotPose | None, stage_mm: float | None) -> None:
        """Keep the instruments' latest values, read back from them."""
        with self._lock:
            self._readings = {"laser_mm": laser_mm, **_pose(robot, moving=False), "stage_mm": stage_mm}

    def robot_pose(self, pose: RobotPose) -> None:
        """Follow the robot while it moves."""
        with self._lock:
            self._readings = {**self._readings, **_pose(pose, moving=True)}

    def alignment(self, summary: dict[str, Any]) -> None:
        """Keep the corner fields of the recorded stack."""
        with self._lock:
            self._alignment = {**summary, "live": False, "time": time.time()}

    def prompt(self, question: str, options: Sequence[str]) -> None:
        """Publish the waiting prompt under a new id."""
        with self._lock:
            self._prompt = {"id": next(self._prompt_ids), "question": question, "options": list(options)}

    def prompt_closed(self) -> None:
        """The prompt was answered."""
        with self._lock:
            self._prompt = None

    def message(self, text: str) -> None:
        """Keep the log line."""
        with self._lock:
            self._messages.append(text)

    def finished(self, status: str) -> None:
        """Record the run's final status and stop the encoder."""
        with self._lock:
            if self._current is not None and status == "complete":
                for entry in self._plan:
                    entry["done"] = True
            self._status, self._prompt = status or "ended", None
        self.close()

    # ------------------------------------------------------------------ the browsers (server threads)
    def answer(self, prompt_id: int, answer: str) -> bool:
        """Answer the prompt ``prompt_id`` if it still waits and ``answer`` is one of its options."""
        with self._lock:
            waiting = self._prompt
            if waiting is None or waiting["id"] != prompt_id or answer not in waiting["options"]:
                return False
        self.remote.post(answer)
        return True

    def request_stop(self) -> bool:
        """Stop the run as Ctrl-C does; False when it is not running."""
        with self._lock:
            stop = self._stop if self._status == "running" else None
            self._stopping = self._stopping or stop is not None
        if stop is None:
            return False
        stop("stopped from the console")
        return True

    def snapshot(self) -> dict[str, Any]:
        """The state as one JSON-ready document."""
        with self._lock:
            return {
                "status": "stopping" if self._stopping and self._status == "running" else self._status,
                "plan": [dict(entry, current=entry["step_id"] == self._current) for entry in self._plan],
                "current": self._current,
                "frames_done": self._frames_done,
                "frames_total": self._frames_total,
                "lab_time_left_s": self._left_s,
                "prompt": self._prompt,
                "readings": dict(self._readings),
                "alignment": self._alignment,
                "messages": list(self._messages),
                "image": {"version": self._image_version, "label": self._image_label},
                "dropped_frames": self.dropped,
            }

    def png(self, which: str) -> bytes | None:
        """The latest ``depth`` or ``intensity`` image as PNG (None before the first frame)."""
        with self._lock:
            return self._png.get(which)

    def close(self) -> None:
        """Stop the encoder thread (after the images queued so far)."""
        if self._encoder.is_alive():
            while True:
                try:
                    self._queue.put(None, timeout=0.5)
                    break
                except queue.Full:
                    continue
            self._encoder.join()

    # ------------------------------------------------------------------ internals
    def _offer(self, frame: Frame, label: str, interval_s: float) -> None:
        now = time.monotonic()
        if now - self._offered < interval_s:
            return
        if self._queue.full():
            self.dropped += 1
            return
        z, factor = decimate(frame.z, MAX_WIDTH)
        intensity, _ = decimate(frame.intensity, MAX_WIDTH)
        height, width = frame.z.shape
        role, params = self._step_info
        try:
            self._queue.put_nowait(Images(z, intensity, factor, _regions(role, params, height, width), label))
            self._offered = now
        except queue.Full:
            self.dropped += 1

    def _encode(self) -> None:
        while (images := self._queue.get()) is not None:
            boxes: list[Box] = [scaled_box(rows, cols, images.factor) for rows, cols in images.regions]
            depth, intensity = to_png(images.z, "viridis", boxes), to_png(images.intensity, "gray", boxes)
            with self._lock:
                self._png = {"depth": depth, "intensity": intensity}
                self._image_label = images.label
                self._image_version += 1


def _regions(role: str, params: dict[str, Any], height: int, width: int) -> list[tuple[slice, slice]]:
    """What the evaluation reads of a step's image (by the step's role): the four corner fields (alignment),
    the central 10 % (offset calibration) or the Depth Quality Tool's central 40 % (every other step)."""
    if role == "alignment":
        try:
            return list(field_slices(height, width, int(params.get("field_px", 10)), params.get("margin_px")).values())
        except ValueError:
            return []
    if role == "offset":
        return [central_roi(height, width)]
    return [dqt_roi(height, width)]


def _pose(pose: RobotPose | None, moving: bool) -> dict[str, Any]:
    """The robot's entries of the console's readings."""
    if pose is None:
        return {"robot_angle_deg": None, "robot_radius_mm": None, "robot_tcp_mm": None, "robot_moving": False}
    return {"robot_angle_deg": pose.angle_deg, "robot_radius_mm": pose.radius_mm,
            "robot_tcp_mm": list(pose.tcp_mm) if pose.tcp_mm is not None else None, "robot_moving": moving}
