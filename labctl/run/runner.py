"""The runner: executes a plan on a lab, writes the run file, survives faults.

It is the only place that handles faults, retries and checkpoints:

* transient device faults (serial timeout, garbled reply, dropped frame,
  camera disconnect) are retried with an exponential backoff, at most
  ``runner.max_attempts`` times without progress, and logged in the step's
  ``faults_json`` / ``retries`` attributes;
* a robot protective stop waits for an operator's confirmation, then recovers;
* anything else, Ctrl-C, SIGTERM and SIGHUP included, puts every device in
  its safe state, marks the run ``aborted`` and stops (exit 1, or 130 for a
  signal); a signal takes effect at the next frame or device operation (a
  second Ctrl-C, or any at an operator prompt: at once), and none can cut the
  safe-state sequence short (labctl.run.signals);
* every step is committed atomically (``complete`` last), so ``resume`` can
  continue at the first step that is not complete.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from typing import Any, TypeVar

from drivers.errors import (
    CameraDisconnected,
    DeviceError,
    DeviceVanished,
    LimitViolation,
    OperatorActionRequired,
    TransientDeviceError,
)
from labctl.errors import Interrupted, RunAborted
from labctl.run.config import Campaign
from labctl.run.lab import Lab
from labctl.run.observer import RunObserver, alignment_summary
from labctl.run.operator import Operator, unlock_confirmation
from labctl.run.planning import PlannedStep, schedule
from labctl.run.progress import Reporter
from labctl.run.signals import StopRequests, signals_ignored
from labctl.run.store import FrameError, RunWriter, StepWriter
from metrics.stack import RoiMean, central_roi
from procedures.targets import confirm_mounted_prompt

T = TypeVar("T")
#: the procedures whose frames the run itself reads back from its file: the slanted edge, whose sharpness gives the
#: best-focus distance of later steps (``_resolved_distance``), in a campaign that has such steps
READ_BACK = frozenset({"slanted_edge"})


def bring_to_safe_state(lab: Lab, report: Callable[[str], None]) -> None:
    """safe_state() on every device; Ctrl-C, SIGTERM and SIGHUP are ignored until all are safe (in the main thread)."""
    with signals_ignored():
        for role, device in lab.devices().items():
            try:
                device.safe_state()
            except Exception as exc:  # a device that cannot even stop must not stop the others
                report(f"warning: {role} safe_state failed: {exc}")


def close_all(lab: Lab, report: Callable[[str], None]) -> None:
    for role, device in lab.devices().items():
        try:
            device.close()
        except Exception as exc:
            report(f"warning: closing {role} failed: {exc}")


def connect_lab(lab: Lab, report: Callable[[str], None], operator: Operator | None = None) -> None:
    """Connect every device; on failure all devices go to their safe state (RunAborted).

    A stage with a ``confirm_unlock`` callback slot (Grbl) found in the Alarm state asks
    ``operator`` whether it may be unlocked."""
    if operator is not None and getattr(lab.stage, "confirm_unlock", False) is None:
        setattr(lab.stage, "confirm_unlock", unlock_confirmation(operator))  # noqa: B010 (Grbl only)
    try:
        for device in lab.devices().values():
            device.connect()
    except (DeviceError, OSError) as exc:
        bring_to_safe_state(lab, report)
        close_all(lab, report)
        raise RunAborted(f"cannot connect devices: {exc}") from None


def absolute_reference(laser_mm: float, depth_origin_offset_mm: float | None) -> dict[str, float]:
    """The step attributes of the reference independent of the camera (docs/runfile.md): the campaign's
    ``devices.camera.depth_origin_offset_mm`` and the laser reading moved to the camera's depth origin,
    ``laser - depth_origin_offset_mm`` (NaN without the offset or without a laser reading)."""
    offset = math.nan if depth_origin_offset_mm is None else float(depth_origin_offset_mm)
    return {"depth_origin_offset_mm": offset, "absolute_reference_mm": laser_mm - offset}


class Runner:
    """Executes a campaign's plan on a connected lab into an open run file."""

    def __init__(
        self, campaign: Campaign, lab: Lab, run: RunWriter, reporter: Reporter, operator: Operator,
        *, resumed: bool = False, observer: RunObserver | None = None,
    ) -> None:
        """``resumed``: the run continues an interrupted one, so the operator re-confirms the mounted
        target before the first step that has no prompt of its own. ``observer`` is told of every step,
        frame, reading and prompt (the live console); with one, the alignment prompt streams preview frames."""
        self.campaign = campaign
        self.lab = lab
        self.run = run
        self.reporter = reporter
        self.operator = operator
        self.cfg = campaign.runner
        laser = campaign.devices.laser
        self.offset_mm: float | None = laser.offset_mm if laser else None
        self.stop = StopRequests()
        self.observer = observer or RunObserver()
        self._watched = observer is not None
        self._focus_mm: float | None = None
        #: the slanted edge's frames are read back from the file only where a later step stands at its best focus
        self._read_back = READ_BACK if any(s.distance_from is not None for s in campaign.steps()) else frozenset()
        self._confirm_target = resumed

    # ------------------------------------------------------------------ driver
    def execute(self) -> None:
        """Run every step that is not complete yet; raise Interrupted / RunAborted on failure.

        The signal handlers stay installed until the devices are safe and the run file is marked,
        so a signal during that sequence is recorded, never a cause to skip it."""
        with self.stop.installed():
            self._execute()

    def _execute(self) -> None:
        plan = schedule(self.campaign)
        done = self.run.completed()
        for attrs in done.values():
            offset = attrs.get("camera_laser_offset_mm")
            if offset is not None and math.isfinite(offset):
                self.offset_mm = float(offset)
        self.reporter.start(plan, done)
        self.observer.started(plan, list(done), self.stop.request)
        status = "aborted"  # what the observer hears, known here even when the run file can no longer be read
        try:
            for planned in plan:
                if planned.step.step_id not in done:
                    self._execute_step(planned)
            self.stop.hold()
            bring_to_safe_state(self.lab, self.reporter.message)
            self.run.set_status("complete")
            status = "complete"
        except (KeyboardInterrupt, Interrupted) as exc:
            reason = "interrupted by the operator (Ctrl-C)" if isinstance(exc, KeyboardInterrupt) else exc.args[0]
            self._abort(reason)
            raise Interrupted(
                f"{reason}; devices are in their safe state and {self.run.path} is marked aborted. "
                f"Continue with: labctl resume {self.run.path}"
            ) from None
        except DeviceVanished as exc:
            self._abort(str(exc))
            raise RunAborted(
                f"run aborted: {exc}. The other devices are in their safe state; {self.run.path} keeps every complete "
                f"step. Once the device is back, continue with: labctl resume {self.run.path}{self._reconnect_option(exc)}"
            ) from None
        except (DeviceError, FrameError, OSError, RuntimeError) as exc:
            self._abort(str(exc))
            raise RunAborted(
                f"run aborted: {exc}. Devices are in their safe state; {self.run.path} keeps every complete "
                f"step. Continue with: labctl resume {self.run.path}"
            ) from None
        except BaseException as exc:  # a bug: devices still go to their safe state, the traceback stays
            self._abort(f"internal error: {type(exc).__name__}: {exc}")
            raise
        finally:
            self.reporter.stop()
            close_all(self.lab, self.reporter.message)
            self.observer.finished(status)

    def _reconnect_option(self, exc: DeviceVanished) -> str:
        """The resume option that finds a vanished device again if it comes back under another port or address."""
        devices = self.campaign.devices
        for role, config in (("stage", devices.stage), ("laser", devices.laser)):
            if config is not None and config.port == exc.connection:
                return f" (add --port {role}=NEW_PORT if it came back under another name than {exc.connection})"
        if devices.robot is not None and devices.robot.host == exc.connection:
            return f" (add --host robot=NEW_HOST if it came back at another address than {exc.connection})"
        return ""

    def _resolved_distance(self, step: Any) -> float:
        """Camera-wall distance of a ``distance_from`` step: the sharp distance of the run's slanted-edge steps."""
        if self._focus_mm is None:
            from labctl.evaluation.sharpness import evaluate_slanted_edge

            result = evaluate_slanted_edge(self.run.steps("slanted_edge"), self.run.camera_info(), lambda _: None)
            focus = result.best_focus_mm if result is not None else math.nan
            if not math.isfinite(focus):
                raise DeviceError("runner", "cannot resolve distance_mm = best_focus: the run's slanted-edge steps "
                                  "have no valid sharpness (see labctl evaluate)")
            self._focus_mm = focus
            self.reporter.message(f"best focus: {focus:g} mm (from the slanted-edge steps; sharp targets go there)")
            if result is not None and result.focus_warning:
                self.reporter.message(f"warning: {result.focus_warning}")
        return self._focus_mm + step.distance_offset_mm

    def _stage_position(self, distance_mm: float) -> float:
        stage = self.campaign.devices.stage
        position = stage.position_for_distance(distance_mm)
        lo, hi = stage.travel_mm
        if not lo <= position <= hi:
            raise LimitViolation("stage", f"resolved distance {distance_mm:g} mm needs stage position {position:g} mm, "
                                          f"outside devices.stage.travel_mm [{lo:g}, {hi:g}]")
        return position

    def _abort(self, reason: str) -> None:
        """Every device to its safe state, then the file marked aborted; later signals are only recorded."""
        self.stop.hold()
        bring_to_safe_state(self.lab, self.reporter.message)
        try:
            self.run.set_status("aborted", reason)
        except Exception as exc:
            self.reporter.message(f"warning: could not mark the run aborted: {exc}")

    # ------------------------------------------------------------------ a step
    def _execute_step(self, planned: PlannedStep) -> None:
        step, lab = planned.step, self.lab
        position = planned.stage_position_mm
        self.stop.check()
        if step.distance_from is not None:
            step = dataclasses.replace(step, distance_mm=self._resolved_distance(step))
            position = self._stage_position(step.distance_mm)
        lab.begin_step(step, planned.start_s)
        self.reporter.step(planned)
        self.observer.step(planned, self.reporter.lab_time_left_s())
        faults: list[dict[str, Any]] = []
        if step.prompt:
            self._confirm(step.prompt)
        elif self._confirm_target:
            self._confirm(confirm_mounted_prompt(step))
        self._confirm_target = False
        if position is not None and lab.stage is not None:
            self._retry("stage move", lambda: lab.stage.move_to(position), faults)
        if step.robot_angle_deg is not None and lab.robot is not None:
            angle, radius = step.robot_angle_deg, step.robot_radius_mm or 0.0
            watch = self.observer.robot_pose if self._watched else None
            self._retry("robot move", lambda: lab.robot.move_on_circle(angle, radius, watch), faults, lab.robot)
        readings: list[float] = []
        if lab.laser is not None:
            laser = lab.laser
            n = self.campaign.devices.laser.readings
            readings = [self._retry("laser reading", laser.measure_mm, faults) for _ in range(n)]
        if self._watched:  # read back for those watching; an unwatched run adds no device traffic
            self.observer.readings(
                sum(readings) / len(readings) if readings else None,
                self._retry("robot pose", lab.robot.pose, faults) if lab.robot is not None else None,
                self._retry("stage position", lab.stage.position_mm, faults) if lab.stage is not None else None)
        settings = {**self.campaign.devices.camera.settings, **step.camera_settings}
        self._retry("camera configure", lambda: lab.camera.configure(step.exposure_us, settings), faults)
        info = lab.camera.info()
        while True:
            writer = self.run.begin_step(step, position, read_back=step.procedure in self._read_back)
            roi = RoiMean(central_roi(info.height, info.width), step.frames) if step.role == "offset" else None
            before = self._camera_temperatures()
            self._capture(writer, faults, roi, settings)
            attrs = self._step_attrs(step, readings, roi, faults)
            after = self._camera_temperatures()
            attrs["camera_temperatures_json"] = json.dumps(
                {name: [before.get(name), after.get(name)] for name in {**before, **after}})
            if step.role != "alignment" or self._alignment_accepted(writer, step, attrs):
                break
        writer.commit(attrs)
        retries = f" ({len(faults)} fault(s) recovered)" if faults else ""
        self.reporter.message(f"{step.step_id} complete{retries}")

    def _camera_temperatures(self) -> dict[str, float]:
        """The camera's temperatures as it reports them (name -> degrees Celsius); empty where it reports none
        or the reading fails (a temperature is a condition to record, never a reason to stop the run)."""
        try:
            return {name: float(value) for name, value in self.lab.camera.temperatures_c().items()}
        except DeviceError:
            return {}

    def _alignment_accepted(self, writer: StepWriter, step: Any, attrs: dict[str, Any]) -> bool:
        """Show the four corner fields and the implied tilt; the operator accepts or measures again."""
        from metrics.alignment import alignment_fields
        from metrics.stack import stack_stats

        x, y, z = (stack_stats(writer.stack(c)).mean for c in ("x", "y", "z"))
        try:
            fields = alignment_fields(x, y, z, int(step.target_params.get("field_px", 10)),
                                      step.target_params.get("margin_px"))
        except ValueError as exc:
            raise DeviceError("camera", f"alignment: {exc}; move the fields with margin_px / field_px") from None
        depths = ", ".join(f"{name.replace('_', ' ')} {value:.1f}" for name, value in fields.depths().items())
        self.reporter.message(f"alignment fields (mm): {depths}; implied tilt about x {fields.tilt_x_deg:+.3f} deg, "
                              f"about y {fields.tilt_y_deg:+.3f} deg")
        self.observer.alignment(alignment_summary(fields))
        question, options = "accept this alignment, or adjust the tilt stage and measure again", ["accept", "measure again"]
        with self.stop.at_once():
            if self._watched:  # the live preview; an operator of a script's own may not take idle=
                choice = self.operator.choose(question, options, idle=lambda: self._preview(step))
            else:
                choice = self.operator.choose(question, options)
        if choice != "accept":
            return False
        attrs["alignment_fields_json"] = json.dumps(fields.fields)
        attrs["tilt_x_deg"] = fields.tilt_x_deg
        attrs["tilt_y_deg"] = fields.tilt_y_deg
        return True

    def _preview(self, step: Any) -> None:
        """One frame from the camera, not recorded, and its four corner fields, for the observer while the
        operator adjusts the target; a frame the camera cannot deliver now is skipped."""
        from metrics.alignment import alignment_fields

        try:
            frame = next(iter(self.lab.camera.capture(1)), None)
        except DeviceError:
            return
        if frame is None:
            return
        try:
            fields = alignment_fields(frame.x, frame.y, frame.z, int(step.target_params.get("field_px", 10)),
                                      step.target_params.get("margin_px"))
        except ValueError:
            self.observer.preview(frame, None)
            return
        self.observer.preview(frame, alignment_summary(fields))

    def _step_attrs(
        self, step: Any, readings: list[float], roi: RoiMean | None, faults: list[dict[str, Any]]
    ) -> dict[str, Any]:
        camera_settings = dict(self.lab.camera.settings())
        attrs: dict[str, Any] = {
            "exposure_us": float(camera_settings.get("exposure_us", step.exposure_us or math.nan)),
            "settings_json": json.dumps(camera_settings, default=str),
            "faults_json": json.dumps(faults),
            "retries": len(faults),
            "prompt": step.prompt or "",
            "distance_source": step.distance_from or "campaign",
        }
        if readings:
            laser_mm = sum(readings) / len(readings)
            if roi is not None:
                offset = roi.value() - laser_mm
                if not math.isfinite(offset):
                    raise DeviceError("camera", f"offset calibration {step.step_id}: the central 10 % x 10 % region "
                                      f"has no valid depth in its {step.frames} frames, so the camera-laser offset is "
                                      "undefined; check that the camera sees the wall at the image centre (exposure, "
                                      "distance, nothing in the way) and resume")
                self.offset_mm = offset
                attrs["camera_laser_offset_mm"] = self.offset_mm
            attrs["laser_distance_mm"] = laser_mm
            attrs["laser_readings_mm"] = readings
            # offset = camera - laser at 2 m, so the camera-frame reference is laser + offset
            attrs["reference_distance_mm"] = laser_mm + self.offset_mm if self.offset_mm is not None else math.nan
            attrs["reference_source"] = "laser"
        else:
            attrs["laser_distance_mm"] = math.nan
            attrs["reference_distance_mm"] = step.distance_mm if step.distance_mm is not None else math.nan
            attrs["reference_source"] = "stage" if step.distance_mm is not None else "none"
        attrs.update(absolute_reference(attrs["laser_distance_mm"], self.campaign.devices.camera.depth_origin_offset_mm))
        return attrs

    def _confirm(self, message: str) -> None:
        """An operator prompt; Ctrl-C or SIGTERM while it waits stops the run at once."""
        with self.stop.at_once():
            self.operator.confirm(message)

    # ------------------------------------------------------------------ faults
    def _note(self, faults: list[dict[str, Any]], operation: str, exc: DeviceError, attempt: int) -> None:
        faults.append({
            "operation": operation,
            "kind": getattr(exc, "kind", type(exc).__name__),
            "message": str(exc),
            "attempt": attempt,
            "lab_time_s": round(self.lab.clock.now(), 3),
        })
        self.reporter.message(f"retrying {operation} after: {exc}")

    def _retry(
        self, operation: str, action: Callable[[], T], faults: list[dict[str, Any]], recoverable: Any = None
    ) -> T:
        """Run ``action``; retry transient faults with backoff; recover operator-confirmed stops."""
        delay = self.cfg.backoff_s
        for attempt in range(1, self.cfg.max_attempts + 1):
            self.stop.check()
            try:
                return action()
            except TransientDeviceError as exc:
                self._note(faults, operation, exc, attempt)
                if attempt == self.cfg.max_attempts:
                    raise DeviceError(exc.device, f"{operation} failed {attempt} times: {exc.message}") from None
                self.lab.clock.sleep(delay)
                delay = min(2 * delay, self.cfg.backoff_max_s)
            except OperatorActionRequired as exc:
                if recoverable is None or attempt == self.cfg.max_attempts:
                    raise
                self._note(faults, operation, exc, attempt)
                self._confirm(f"{exc}: check that the cell is safe, then confirm to recover and continue")
                recoverable.recover()
        raise AssertionError("unreachable")

    def _capture(
        self, writer: StepWriter, faults: list[dict[str, Any]], roi: RoiMean | None, settings: dict[str, Any]
    ) -> None:
        """Record the stack; continue from the frame a transient fault interrupted.

        The retry budget counts consecutive failures at the same frame; any
        progress resets it and the backoff.
        """
        camera, n = self.lab.camera, writer.step.frames
        k, failures, failed_at, delay = 0, 0, -1, self.cfg.backoff_s
        while k < n:
            before = k
            try:
                for frame in camera.capture(n - k, first_index=k):
                    self.stop.check()
                    writer.write(k, frame)
                    if self._watched:
                        self.observer.frame(writer.step.step_id, k, frame, self.reporter.lab_time_left_s())
                    if roi is not None:
                        roi.add(frame.z)
                    k += 1
                    self.reporter.frames()
                    if k == n:
                        break
                if k == before:
                    raise DeviceError("camera", f"delivered no frame for frame {k} of {n}")
            except TransientDeviceError as exc:
                if k != failed_at:
                    failures, failed_at, delay = 0, k, self.cfg.backoff_s
                failures += 1
                self._note(faults, f"capture frame {k}", exc, failures)
                if failures >= self.cfg.max_attempts:
                    raise DeviceError(exc.device, f"capture stuck at frame {k} of {n} after {failures} attempts: "
                                      f"{exc.message}; the camera stopped delivering frames: check its cable, power "
                                      "and network") from None
                self.lab.clock.sleep(delay)
                delay = min(2 * delay, self.cfg.backoff_max_s)
                if isinstance(exc, CameraDisconnected):
                    self._reconnect_camera(settings, writer.step.exposure_us, faults)

    def _reconnect_camera(self, settings: dict[str, Any], exposure_us: float | None, faults: list[dict[str, Any]]) -> None:
        camera = self.lab.camera
        try:
            camera.close()
        except DeviceError:
            pass
        self._retry("camera reconnect", camera.connect, faults)
        self._retry("camera configure", lambda: camera.configure(exposure_us, settings), faults)
