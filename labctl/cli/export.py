"""``labctl export``: the organized point cloud of one step as PCD or PLY (README.md, Command line, Thesis 2024, 6.7)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from labctl.cli.inputs import warn
from labctl.cli.outputs import OutputFile, output_file
from labctl.errors import InputError

if TYPE_CHECKING:
    import numpy as np

    from labctl.run.store import RunReader, StepRecord


def step_cloud(record: StepRecord, frame: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) points and (H, W) intensity of a step: the stack mean (docs/metrics.md, Stacks) or frame ``frame``.

    A point is invalid (NaN in x, y and z) where any coordinate is.
    """
    import numpy as np

    from metrics.stack import stack_stats

    if frame is None:
        xyz = np.stack([stack_stats(record.read(c)).mean for c in "xyz"], axis=-1)
        intensity = stack_stats(record.read("intensity")).mean
    else:
        xyz = np.stack([record.frame(c, frame) for c in "xyz"], axis=-1).astype(np.float64)
        intensity = record.frame("intensity", frame).astype(np.float64)
    xyz[~np.isfinite(xyz).all(axis=-1)] = np.nan
    return xyz, intensity


def _complete_step(reader: RunReader, step_id: str) -> StepRecord:
    steps = reader.file["steps"]
    if step_id not in steps:
        known = ", ".join(steps.keys()) or "none"
        raise InputError(f"--step {step_id!r}: {reader.path} has no such step (its steps: {known})")
    if not bool(steps[step_id].attrs.get("complete", False)):
        raise InputError(f"--step {step_id!r}: the step in {reader.path} is incomplete (the run stopped during it; "
                         f"'labctl resume {reader.path}' redoes it)")
    return reader.step(step_id)


def _matching_suffix(output: Path, fmt: str) -> None:
    """Refuse a .pcd file holding PLY (or the reverse); warn when the name has neither extension, since point-cloud
    tools choose their reader by it."""
    named = {".pcd": "pcd", ".ply": "ply"}.get(output.suffix.lower())
    if named is not None and named != fmt:
        raise InputError(f"--format {fmt} does not match -o {output}, a .{named} name: write -o "
                         f"{output.with_suffix('.' + fmt)}, or give --format {named}")
    if named is None:
        warn(f"-o {output} has no .{fmt} extension; CloudCompare and Open3D choose their reader by it: "
             f"name it {output.with_suffix('.' + fmt)}")


@click.command("export")
@click.argument("run_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--step", "step_id", required=True, help="step id, e.g. 00002_boehler_star")
@click.option("--format", "fmt", required=True, type=click.Choice(["pcd", "ply"]), help="file format")
@click.option("-o", "--output", required=True, type=OutputFile("cloud.pcd"), help="file to write")
@click.option("--frame", type=int, help="export frame K (0-based) instead of the mean of the step's frames")
@click.option("--ascii", "as_text", is_flag=True, help="text data instead of binary")
@click.option("--force", is_flag=True, help="overwrite an existing output file")
def export(run_file: Path, step_id: str, fmt: str, output: Path, frame: int | None, as_text: bool, force: bool) -> None:
    """Write the organized point cloud of one step of RUN_FILE (mm, camera frame) as PCD or PLY.

    PCD keeps the image organization (invalid points as NaN); PLY holds the
    valid points only. The cloud is the mean of the step's frames unless
    --frame K. An existing OUTPUT is only replaced with --force.
    """
    import numpy as np

    from labctl.report.pointcloud_io import write_pcd, write_ply
    from labctl.run.store import RunReader

    if output.exists() and output.resolve() == run_file.resolve():
        raise InputError(f"-o {output} is the run file itself")
    _matching_suffix(output, fmt)
    output_file(output, "-o", force=force)
    with RunReader(run_file) as reader:
        record = _complete_step(reader, step_id)
        frames = record.group["z"].shape[0]
        if frame is not None and not 0 <= frame < frames:
            raise InputError(f"--frame {frame}: step {step_id} has frames 0..{frames - 1}")
        xyz, intensity = step_cloud(record, frame)
    what = f"frame {frame}" if frame is not None else f"mean of {frames} frames"
    comment = f"labctl export of {run_file.name} step {step_id} ({what}); mm, camera frame x right y down z forward"
    write = write_pcd if fmt == "pcd" else write_ply
    write(output, xyz, intensity, binary=not as_text, comment=comment)
    valid = int(np.isfinite(xyz).all(axis=-1).sum())
    click.echo(f"{output}: {xyz.shape[1]} x {xyz.shape[0]} points ({valid} valid), {what} of {step_id}")
