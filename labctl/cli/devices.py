"""``labctl device laser|stage|camera`` and ``labctl devices``: single devices, outside any campaign.

Exit codes as for every command (README.md, Command line): 2 for bad arguments, 1 when the device
fails or its SDK is missing; devices are left in their safe state on every path.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from drivers.errors import DeviceError, LimitViolation
from labctl.cli.inputs import POSITIVE, Number, warn_run_suffix
from labctl.cli.outputs import OutputFile, output_file
from labctl.errors import InputError, RunAborted
from labctl.jsondoc import dumps

if TYPE_CHECKING:
    from drivers.protocols import DepthCamera


@contextmanager
def _device_errors() -> Iterator[None]:
    """Device failures become exit code 1 with the driver's message (it names device and port);
    a target outside the limits, refused before anything moved, is bad input (exit code 2)."""
    try:
        yield
    except LimitViolation as exc:
        raise InputError(str(exc)) from None
    except DeviceError as exc:
        raise RunAborted(str(exc)) from None


@contextmanager
def _driver_options() -> Iterator[None]:
    """A driver that rejects its options (ValueError from its constructor) means bad input (exit code 2)."""
    try:
        yield
    except ValueError as exc:
        raise InputError(str(exc)) from None


@click.group()
def device() -> None:
    """Drive one device directly: read the laser, move the stage, grab a camera stack."""


@device.command()
@click.option("--port", required=True, help="serial port of the Dimetix sensor, e.g. /dev/ttyUSB1")
@click.option("--baud", type=click.IntRange(min=1), default=19200, show_default=True)
@click.option("--count", type=click.IntRange(min=1), default=1, show_default=True, help="single measurements")
@click.option("--json", "as_json", is_flag=True, help='print {"distances_mm": [...]}')
def laser(port: str, baud: int, count: int, as_json: bool) -> None:
    """Read the Dimetix laser distance meter COUNT times (then switch its laser off)."""
    from drivers.laser import read_distances

    with _device_errors(), _driver_options():
        distances = read_distances(port, baud, count)
    if as_json:
        click.echo(dumps({"distances_mm": distances}, indent=None))
    else:
        for value in distances:
            click.echo(f"{value:.1f} mm")


@device.command()
@click.option("--port", required=True, help="serial port of the stage controller")
@click.option("--protocol", required=True, type=click.Choice(["zaber", "grbl"]))
@click.option("--baud", type=click.IntRange(min=1), help="default: 115200")
@click.option("--home", is_flag=True, help="run the homing cycle first")
@click.option("--move-mm", type=Number(minimum=0.0, why=": positions count from home"),
              help="absolute target position in mm (from home, 0 mm)")
@click.option("--mm-per-microstep", type=POSITIVE, help="Zaber: microstep size")
@click.option("--axis", help="Zaber: axis number (1); Grbl: axis letter (X)")
@click.option("--unlock-alarm", is_flag=True,
              help="Grbl: unlock ($X) an alarm found at connect without asking (default: ask on a terminal)")
@click.option("--json", "as_json", is_flag=True, help='print {"position_mm": ...}')
def stage(
    port: str, protocol: str, baud: int | None, home: bool, move_mm: float | None,
    mm_per_microstep: float | None, axis: str | None, unlock_alarm: bool, as_json: bool,
) -> None:
    """Optionally home and move the linear stage, then print its position."""
    from drivers.stage import move_stage
    from labctl.run.operator import Operator, unlock_confirmation

    options: dict[str, Any] = {} if baud is None else {"baud": baud}
    if protocol == "zaber":
        if mm_per_microstep is None:
            raise InputError("--mm-per-microstep is required for a Zaber stage (its microstep size in mm, datasheet)")
        if axis is not None and not axis.isdigit():
            raise InputError(f"--axis of a Zaber stage is a number, got {axis!r}")
        if unlock_alarm:
            raise InputError("--unlock-alarm applies to Grbl stages only")
        options.update(mm_per_microstep=mm_per_microstep, axis=int(axis or 1))
    else:
        if mm_per_microstep is not None:
            raise InputError("--mm-per-microstep applies to Zaber stages only")
        options["axis"] = axis or "X"
        operator = Operator(automatic=False, report=lambda message: click.echo(message, err=True))
        options["confirm_unlock"] = (lambda _: True) if unlock_alarm else unlock_confirmation(operator)
    with _device_errors(), _driver_options():
        position = move_stage(port, protocol, home=home, move_mm=move_mm, **options)
    click.echo(dumps({"position_mm": position}, indent=None) if as_json else f"{position:.4f} mm")


def _parse_settings(pairs: Sequence[str]) -> dict[str, Any]:
    settings: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep or not key:
            raise InputError(f"--setting {pair!r} is not KEY=VALUE")
        try:
            settings[key] = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            settings[key] = text  # a bare word is a string
    return settings


def _capture_file(
    camera: DepthCamera, output: Path, frames: int, exposure_us: float | None, settings: dict[str, Any],
    description: str,
) -> dict[str, Any]:
    """Grab one stack into a new run file holding one ``capture`` step (docs/runfile.md)."""
    import numpy as np

    from labctl.run.store import RunWriter
    from procedures.steps import Step

    camera.configure(exposure_us, settings)
    step = Step(index=0, procedure="capture", target="scene", frames=frames, exposure_us=exposure_us)
    writer = RunWriter.create(
        output, campaign_toml=description, simulated=False,
        devices={"camera": (camera.identity(), camera.settings())}, camera=camera.info(), steps=1,
    )
    try:
        steps = writer.begin_step(step, None)
        valid = 0.0
        for k, frame in enumerate(camera.capture(frames)):
            steps.write(k, frame)
            valid += float(np.isfinite(frame.z).mean()) / frames
        applied = dict(camera.settings())
        steps.commit({
            "exposure_us": float(applied.get("exposure_us", exposure_us if exposure_us is not None else math.nan)),
            "settings_json": json.dumps(applied, default=str), "faults_json": "[]", "retries": 0, "prompt": "",
            "laser_distance_mm": math.nan, "reference_distance_mm": math.nan, "reference_source": "none",
        })
        writer.set_status("complete")
    except BaseException:
        writer.close()
        output.unlink(missing_ok=True)  # nothing complete was captured
        raise
    writer.close()
    info = camera.info()
    return {"run_file": str(output), "step_id": step.step_id, "frames": frames, "width": info.width,
            "height": info.height, "valid_fraction": round(valid, 6)}


@device.command()
@click.option("--backend", required=True, type=click.Choice(["realsense", "blaze", "amt100", "flexx2"]))
@click.option("--playback", type=click.Path(dir_okay=False, path_type=Path), help="recording (.bag, .db3, .rrf)")
@click.option("--frames", type=click.IntRange(min=1), default=1, show_default=True)
@click.option("-o", "--output", required=True, type=OutputFile("capture.h5"), help="run file")
@click.option("--serial", help="which camera, if several are connected")
@click.option("--producer", type=click.Path(dir_okay=False, path_type=Path), help="GenTL producer .cti")
@click.option("--sdk", type=click.Choice(["pypylon", "harvesters"]), default="pypylon", show_default=True)
@click.option("--exposure-us", type=POSITIVE)
@click.option("--setting", "settings", multiple=True, help="backend setting KEY=VALUE (repeatable)")
@click.option("--json", "as_json", is_flag=True, help="print a JSON summary")
def camera(
    backend: str, playback: Path | None, frames: int, output: Path, serial: str | None, producer: Path | None,
    sdk: str, exposure_us: float | None, settings: tuple[str, ...], as_json: bool,
) -> None:
    """Grab a stack of FRAMES from one camera (or a recording) into a one-step run file."""
    from drivers.camera import open_camera

    if output.exists():
        raise InputError(f"{output} already exists; choose another -o")
    output_file(output, "-o")
    warn_run_suffix(output)
    for path, option in ((playback, "--playback"), (producer, "--producer")):
        if path is not None and not path.is_file():
            raise InputError(f"{option} file {path} does not exist")
    if playback is not None and exposure_us is not None:
        raise InputError("--exposure-us cannot apply to a recording (--playback): it plays as recorded")
    parsed = _parse_settings(settings)
    with _driver_options():
        cam = open_camera(backend, serial=serial, playback=playback, sdk=sdk,
                          producers=[producer] if producer else None)
    description = (
        "# labctl device camera: one stack, no procedure\n[campaign]\nname = \"device-camera\"\n\n"
        f"[devices.camera]\nbackend = {json.dumps(backend)}\n"
        + (f"playback = {json.dumps(str(playback))}\n" if playback else "")
        + (f"serial = {json.dumps(serial)}\n" if serial else "")
    )
    try:
        with _device_errors():
            cam.connect()
            summary = _capture_file(cam, output, frames, exposure_us, parsed, description)
    finally:
        cam.safe_state()
        cam.close()
    if as_json:
        click.echo(dumps(summary, indent=None))
    else:
        click.echo(f"{frames} frame(s) of {summary['width']}x{summary['height']} in {output} "
                   f"(step {summary['step_id']}, {summary['valid_fraction']:.1%} valid points)")


@click.command()
@click.option("--json", "as_json", is_flag=True, help="print the inventory as one JSON document")
def devices(as_json: bool) -> None:
    """List what is connected: serial ports, RealSense, GenTL producers and devices, pylon, Royale."""
    from drivers.discovery import discover

    sections = discover()
    if as_json:
        click.echo(dumps({"sections": [s.as_dict() for s in sections]}))
        return
    for section in sections:
        if not section.available:
            click.echo(f"{section.name}: {section.note}")
            continue
        listed = "; ".join(section.devices) if section.devices else "none found"
        click.echo(f"{section.name}: {listed}" + (f" ({section.note})" if section.note else ""))
