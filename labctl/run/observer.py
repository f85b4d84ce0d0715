"""What a run tells those who watch it (the live console, labctl.console): a small interface the runner
calls at each event. The runner never waits on an observer: an observer that keeps data copies it, or drops
it, and returns at once (a frame handed over must not slow the recording)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from drivers.protocols import Frame, RobotPose
from labctl.run.planning import PlannedStep


class RunObserver:
    """Every event as a method that does nothing; an observer overrides those it shows."""

    def started(self, plan: Sequence[PlannedStep], done: Sequence[str], stop: Callable[[str], None]) -> None:
        """The run starts with ``plan``; the steps ``done`` are already complete (resume). ``stop(reason)``
        stops the run as Ctrl-C does (devices safe, run file aborted and resumable), from any thread."""

    def step(self, planned: PlannedStep, lab_time_left_s: float) -> None:
        """A step starts (its prompt, moves and capture follow)."""

    def frame(self, step_id: str, index: int, frame: Frame, lab_time_left_s: float) -> None:
        """Frame ``index`` of ``step_id`` was written (the arrays are the recorded ones: copy, never change)."""

    def preview(self, frame: Frame, alignment: dict[str, Any] | None) -> None:
        """A frame grabbed between stacks while the operator adjusts the target (not recorded), with the
        alignment fields computed on it (``alignment_summary``) at the alignment step."""

    def readings(self, laser_mm: float | None, robot: RobotPose | None, stage_mm: float | None) -> None:
        """The laser's mean reading of the step, and the robot's pose and the stage's position read back from
        them once they were moved (None: the device is absent)."""

    def robot_pose(self, pose: RobotPose) -> None:
        """The robot's pose read back while it moves (a few times a second, from the thread that moves it)."""

    def alignment(self, summary: dict[str, Any]) -> None:
        """The alignment step's four corner fields and implied tilt of a recorded stack."""

    def prompt(self, question: str, options: Sequence[str]) -> None:
        """The run waits for the operator (``options``: the answers; a single one for a confirmation)."""

    def prompt_closed(self) -> None:
        """The operator answered, at the terminal or elsewhere."""

    def message(self, text: str) -> None:
        """A log line of the run."""

    def finished(self, status: str) -> None:
        """The run ended with the run file's ``status`` (complete or aborted)."""


def alignment_summary(fields: Any) -> dict[str, Any]:
    """An :class:`metrics.alignment.AlignmentFields` as plain values: depths (mm) per corner and the tilts (deg)."""
    return {"depths_mm": {k: float(v) for k, v in fields.depths().items()},
            "tilt_x_deg": float(fields.tilt_x_deg), "tilt_y_deg": float(fields.tilt_y_deg)}
