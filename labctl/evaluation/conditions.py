"""The conditions behind an evaluation's figures, as the run files record them: which file (its SHA-256), recorded
by which labctl, when, with which devices (the camera and the reference instruments: stage, laser meter, robot;
model, serial, firmware), which exposure times, and the camera's temperatures where it reports them (the range over
the steps of each sensor's readings before and after every stack).
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import NotRequired, TypedDict

from labctl.run.digest import kept_digest, sha256_of
from labctl.run.store import RunReader, StepRecord


class DeviceRecord(TypedDict):
    """A device as the run file records it."""

    role: str
    backend: str
    model: str
    serial: str
    firmware: str


class RunConditions(TypedDict):
    """One run file's conditions: its path and SHA-256, the labctl version that recorded it, when it was created,
    its status, whether it was simulated, its devices, the exposure times (µs) its steps used (empty where no
    step states one) and per temperature sensor of the camera its lowest and highest reading (°C; empty where the
    camera reports none or the file predates the record)."""

    path: str
    sha256: str
    recorded_by: str
    created: str
    status: str
    simulated: bool
    devices: list[DeviceRecord]
    exposures_us: list[float]
    camera_temperatures_c: NotRequired[dict[str, list[float]]]  # from layout 1.1 on


class BackgroundHashes:
    """The SHA-256 of run files: the one kept beside a file where it still holds (labctl/run/digest.py), else
    computed on a thread of its own beside the evaluation (the hash reads the whole file, the evaluation mostly
    computes). A context manager: leaving it stops a hash still running."""

    def __init__(self, paths: Sequence[Path]) -> None:
        self._stop = threading.Event()
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sha256")
        self._futures: list[Future[str]] = [self._kept_or_computed(Path(p)) for p in paths]

    def _kept_or_computed(self, path: Path) -> Future[str]:
        kept = kept_digest(path)
        if kept is None:
            return self._pool.submit(sha256_of, path, self._stop)
        future: Future[str] = Future()
        future.set_result(kept)
        return future

    def results(self) -> list[str]:
        """Every file's hash, waiting for those still running."""
        return [f.result() for f in self._futures]

    def __enter__(self) -> BackgroundHashes:
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._pool.shutdown(wait=True, cancel_futures=True)


def run_conditions(reader: RunReader, sha256: str) -> RunConditions:
    """The conditions ``reader``'s run file records (``sha256``: the file's hash)."""
    devices: list[DeviceRecord] = [
        {"role": role, **{key: str(attrs.get(key, "unknown")) for key in ("backend", "model", "serial", "firmware")}}
        for role, attrs in reader.devices.items()  # type: ignore[misc]  # the four keys above
    ]
    steps = reader.steps()
    exposures = {float(s.attrs["exposure_us"]) for s in steps
                 if isinstance(s.attrs.get("exposure_us"), (int, float)) and math.isfinite(s.attrs["exposure_us"])}
    return {"path": str(reader.path), "sha256": sha256, "recorded_by": str(reader.attrs.get("labctl_version", "unknown")),
            "created": str(reader.attrs.get("created", "unknown")), "status": str(reader.attrs.get("status", "unknown")),
            "simulated": bool(reader.attrs.get("simulated", False)), "devices": devices,
            "exposures_us": sorted(exposures), "camera_temperatures_c": camera_temperature_ranges(steps)}


def camera_temperature_ranges(steps: Sequence[StepRecord]) -> dict[str, list[float]]:
    """Per temperature sensor of the camera, [lowest, highest] of its readings before and after every stack
    (the steps' ``camera_temperatures_json``; docs/runfile.md)."""
    readings: dict[str, list[float]] = {}
    for step in steps:
        try:
            recorded = json.loads(str(step.attrs.get("camera_temperatures_json", "{}")))
        except json.JSONDecodeError:
            continue
        for sensor, values in recorded.items() if isinstance(recorded, dict) else ():
            readings.setdefault(str(sensor), []).extend(
                float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(v))
    return {sensor: [min(values), max(values)] for sensor, values in readings.items() if values}
