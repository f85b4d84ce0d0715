"""``labctl info RUN.h5 [--json]``: a run file's header and its steps."""

from __future__ import annotations

from pathlib import Path

import click

from labctl.jsondoc import dumps


def _position(step: dict) -> str:
    parts = []
    if step.get("stage_position_mm") is not None:
        parts.append(f"stage {step['stage_position_mm']:g} mm")
    if step.get("robot_angle_deg") is not None:
        parts.append(f"robot {step['robot_angle_deg']:g} deg")
    return ", ".join(parts) or "-"


@click.command()
@click.argument("run_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="print one JSON document")
def info(run_file: Path, as_json: bool) -> None:
    """Show RUN_FILE's header (campaign, status, size, compression) and every step with its status."""
    from labctl.run.diskspace import format_bytes
    from labctl.run.runinfo import run_info

    doc = run_info(run_file)
    if as_json:
        click.echo(dumps(doc))
        return
    kind = "simulated" if doc["simulated"] else "measured"
    reason = f" ({doc['status_reason']})" if doc["status_reason"] else ""
    click.echo(f"{doc['file']}: campaign {doc['campaign'] or '-'}, {kind}, status {doc['status']}{reason}")
    cam = doc["camera"]
    click.echo(f"created {doc['created']} by labctl {doc['labctl_version']}; {format_bytes(doc['size_bytes'])} on disk, "
               f"compression {doc['compression']}; camera {cam['width']} x {cam['height']}")
    if doc["damage"]:
        click.echo(f"damaged: {doc['damage']}; 'labctl resume {run_file} --into NEW.h5' continues the run")
    click.echo(f"steps {doc['steps_complete']}/{doc['steps_total']} complete, "
               f"frames {doc['frames_complete']}/{doc['frames_total']}")
    click.echo(f"{'step':<28} {'status':<10} {'target':<14} {'position':<28} {'frames':>6}")
    for s in doc["steps"]:
        click.echo(f"{s['step_id']:<28} {s['status']:<10} {s.get('target', '-'):<14} {_position(s):<28} "
                   f"{s.get('frames', 0):>6}")
