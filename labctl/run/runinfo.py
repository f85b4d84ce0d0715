"""What a run file holds: its header and every step with status, target, position and frames.

Read-only; works on complete, aborted and interrupted (``running``) files alike. Steps the
stored campaign plans but the file does not hold yet are listed as ``pending``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py

from labctl.errors import InputError
from labctl.run import compression as codecs
from labctl.run.config import parse_campaign
from labctl.run.salvage import inspect
from labctl.run.store import RunReader, finite_or_none


def _text(value: Any) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _step(step_id: str, group: h5py.Group) -> dict[str, Any]:
    a = group.attrs
    return {
        "step_id": step_id,
        "status": "complete" if bool(a.get("complete", False)) else "unfinished",
        "procedure": _text(a.get("procedure", "")),
        "target": _text(a.get("target", "")),
        "distance_mm": finite_or_none(a.get("distance_mm")),
        "stage_position_mm": finite_or_none(a.get("stage_position_mm")),
        "robot_angle_deg": finite_or_none(a.get("robot_angle_deg")),
        "frames": int(a.get("frames", 0)),
        "started": _text(a.get("started", "")),
        "finished": _text(a.get("finished", "")),
    }


def run_info(path: Path) -> dict[str, Any]:
    """The header of run file ``path`` and its steps, in execution order (a JSON-ready dict); InputError,
    with what can be recovered, when the file is damaged beyond listing its steps."""
    try:
        return _run_info(path)
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        cause = (str(exc).splitlines() or [type(exc).__name__])[0]
        salvage = inspect(path)
        advice = (f"'labctl resume {path} --into NEW.h5' continues the run in a new file"
                  if salvage.header is None else "start the run again with labctl run")
        raise InputError(f"{path} is damaged ({cause}); {salvage.summary()}; {advice}") from None


def _run_info(path: Path) -> dict[str, Any]:
    with RunReader(path) as reader:
        attrs, f = reader.attrs, reader.file
        steps = []
        try:
            ids, damage = sorted(f["steps"].keys()), None
        except (OSError, KeyError, RuntimeError, ValueError):  # a flush adding a step cut short
            ids, damage = [], inspect(path).summary()
        for step_id in ids:
            try:
                steps.append(_step(step_id, f["steps"][step_id]))
            except (KeyError, OSError, RuntimeError):  # a step cut off mid-creation
                steps.append({"step_id": step_id, "status": "unfinished"})
        try:
            campaign = parse_campaign(_text(attrs.get("campaign_toml", "")), f"{path} (stored campaign)")
        except InputError:
            campaign = None  # e.g. a 'labctl device camera' capture: no procedures
        known = {s["step_id"] for s in steps}
        if campaign is not None:
            steps += [{"step_id": s.step_id, "status": "pending", "procedure": s.procedure, "target": s.target,
                       "distance_mm": s.distance_mm, "stage_position_mm": None, "robot_angle_deg": s.robot_angle_deg,
                       "frames": s.frames, "started": "", "finished": ""}
                      for s in campaign.steps() if s.step_id not in known]
        z = next((f["steps"][s["step_id"]]["z"] for s in steps if s["status"] == "complete"), None)
        return {
            "file": str(path),
            "campaign": campaign.campaign.name if campaign is not None else None,
            "status": attrs.get("status"),
            "status_reason": attrs.get("status_reason", ""),
            "simulated": bool(attrs.get("simulated", False)),
            "created": attrs.get("created"),
            "labctl_version": attrs.get("labctl_version"),
            "size_bytes": path.stat().st_size,
            "compression": _text(attrs.get("compression", "none")),
            "filters": codecs.describe(z) if z is not None else None,
            "camera": {"width": reader.camera.width, "height": reader.camera.height,
                       "frame_rate_hz": reader.camera.frame_rate_hz},
            "steps_complete": sum(s["status"] == "complete" for s in steps),
            "steps_total": len(steps),
            "frames_complete": sum(s.get("frames", 0) for s in steps if s["status"] == "complete"),
            "frames_total": sum(s.get("frames", 0) for s in steps),
            "steps": steps,
            "damage": damage,
        }
