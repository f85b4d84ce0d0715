"""The HDF5 run file (docs/runfile.md): layout, crash-safe writing, reading.

Crash safety. A run file must stay readable whatever happens (kill -9, power
loss during a stack). The writer therefore

* creates the file under a temporary name and renames it into place, so the
  path either does not exist or holds a valid file;
* creates a step's group and datasets, then flushes, before the first frame;
* stores one frame per chunk, compressed losslessly by default (labctl.run.compression;
  ``compression = "none"``: allocated at creation, ``ALLOC_TIME_EARLY``, and written
  as raw chunks); the metadata cache never evicts while the file is open, so HDF5
  metadata reaches the disk only at the flushes below, and a crash between them
  leaves the file as it was at the last one;
* checks before each step that the disk has room for it (labctl.run.diskspace), so
  a run stops before the disk fills;
* writes the step's attributes at the end, ``complete = True`` last, then
  flushes and fsyncs.

A step without ``complete = True`` is unfinished and is discarded by resume.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from drivers.protocols import CameraInfo, DeviceIdentity, Frame
from labctl.errors import InputError
from labctl.run import compression as codecs
from labctl.run.diskspace import ensure_free, frame_bytes
from labctl.run.filekind import not_a_run_file
from procedures.steps import Step

FORMAT = "labctl-run"
FORMAT_VERSION = 1
CHANNELS = ("x", "y", "z", "intensity", "confidence")
STATUSES = ("running", "complete", "aborted")


def labctl_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("labctl")
    except PackageNotFoundError:
        return "0+unknown"


def now_iso() -> str:
    """Current UTC time, ISO 8601 with milliseconds."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def finite_or_none(value: Any) -> float | None:
    """A stored attribute as a float, None where it is missing, not a number, or NaN / infinite (the run file's
    way of saying "none": no stage position on a robot step, no robot angle on a stage step)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _nan_if_none(value: float | None) -> float:
    return math.nan if value is None else float(value)


def _fsync(f: h5py.File) -> None:
    f.flush()
    handle = f.id.get_vfd_handle()
    if isinstance(handle, int):
        os.fsync(handle)


class FrameError(ValueError):
    """A frame from a camera that does not fit the announced format."""


def _keep_metadata_until_flush(f: h5py.File) -> None:
    """Disable metadata-cache evictions (H5Pset_mdc_config: ``evictions_enabled`` needs the automatic
    resize modes off): dirty metadata, such as the chunk index of compressed frames, reaches the file
    only at an explicit flush, never half-way through a step."""
    config = f.id.get_mdc_config()
    config.incr_mode = config.flash_incr_mode = config.decr_mode = 0
    config.evictions_enabled = False
    f.id.set_mdc_config(config)


def _early_alloc_dcpl() -> h5py.h5p.PropDCID:
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    return dcpl


class StepWriter:
    """Writes the frames of one step, then commits it."""

    def __init__(self, run: RunWriter, group: h5py.Group, step: Step, camera: CameraInfo) -> None:
        self.run = run
        self.group = group
        self.step = step
        self.shape = (camera.height, camera.width)
        self.confidence_dtype = np.dtype(camera.confidence_dtype)
        self._datasets = {name: group[name] for name in CHANNELS}
        self._timestamps = group["timestamp"]
        self._raw_chunks = run.compression == "none"
        self._frame_space = h5py.h5s.create_simple((1, *self.shape))

    def write(self, k: int, frame: Frame) -> None:
        """Store frame ``k`` of the stack; FrameError if its arrays do not fit."""
        if not 0 <= k < self.step.frames:
            raise FrameError(f"frame index {k} outside 0..{self.step.frames - 1}")
        for name in CHANNELS:
            array = np.asarray(getattr(frame, name))
            if array.shape != self.shape:
                raise FrameError(f"frame {k}: {name} has shape {array.shape}, expected {self.shape}")
            dtype = self.confidence_dtype if name == "confidence" else np.float32
            data = np.ascontiguousarray(array, dtype=dtype)
            dataset = self._datasets[name].id
            if self._raw_chunks:  # one frame is exactly one uncompressed chunk: no selection or filter machinery
                dataset.write_direct_chunk((k, 0, 0), data)
            else:  # one chunk through the filter pipeline
                space = dataset.get_space()
                space.select_hyperslab((k, 0, 0), (1, *self.shape))
                dataset.write(self._frame_space, space, data.reshape(1, *self.shape))
        self._timestamps[k] = float(frame.timestamp)

    def commit(self, attrs: Mapping[str, Any]) -> None:
        """Write the step's attributes, ``complete = True`` last, and make it durable."""
        for key, value in attrs.items():
            self.group.attrs[key] = value
        self.group.attrs["finished"] = now_iso()
        self.group.attrs["complete"] = True
        _fsync(self.run.file)


class RunWriter:
    """An open run file that steps are appended to."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        try:
            self.file = h5py.File(self.path, "r+")
        except OSError as exc:
            raise InputError(f"cannot open run file {self.path} for writing: {exc}") from None
        _check_format(self.file, self.path)
        _keep_metadata_until_flush(self.file)

    # ------------------------------------------------------------------ create
    @classmethod
    def create(
        cls,
        path: str | Path,
        *,
        campaign_toml: str,
        simulated: bool,
        devices: Mapping[str, tuple[DeviceIdentity, Mapping[str, Any]]],
        camera: CameraInfo,
        sim: tuple[str, int] | None = None,
        compression: str = codecs.DEFAULT,
    ) -> RunWriter:
        """Create a new run file (atomically: written aside, then renamed into place); frames are
        stored with ``compression`` (one of labctl.run.compression.COMPRESSIONS)."""
        path = Path(path)
        codecs.dataset_options(compression)  # an unknown name fails before anything is written
        if path.exists():
            raise InputError(existing_output_advice(path))
        tmp = path.with_name(f".{path.name}.creating")
        with h5py.File(tmp, "w") as f:
            f.attrs.update(
                format=FORMAT,
                format_version=FORMAT_VERSION,
                labctl_version=labctl_version(),
                created=now_iso(),
                campaign_toml=campaign_toml,
                status="running",
                simulated=bool(simulated),
                compression=compression,
            )
            for role, (ident, settings) in devices.items():
                g = f.create_group(f"devices/{role}")
                g.attrs.update(
                    backend=ident.backend, model=ident.model, serial=ident.serial,
                    firmware=ident.firmware, settings_json=json.dumps(dict(settings), default=str),
                )
            cam = f.create_group("camera")
            cam.attrs.update(
                width=camera.width, height=camera.height, fov_deg=np.array(camera.fov_deg, float),
                pixel_pitch_um=camera.pixel_pitch_um, frame_rate_hz=camera.frame_rate_hz,
                wavelength_nm=camera.wavelength_nm, confidence_dtype=camera.confidence_dtype,
            )
            f.create_group("steps")
            if sim is not None:
                g = f.create_group("sim")
                g.attrs.update(model_toml=sim[0], seed=int(sim[1]))
            _fsync(f)
        os.replace(tmp, path)
        return cls(path)

    # ------------------------------------------------------------------ state
    @property
    def attrs(self) -> h5py.AttributeManager:
        return self.file.attrs

    def camera_info(self) -> CameraInfo:
        return _camera_info(self.file)

    @property
    def compression(self) -> str:
        """How frames are stored (files written before compression existed: ``none``)."""
        value = self.file.attrs.get("compression", "none")
        return value.decode() if isinstance(value, bytes) else str(value)

    def completed(self) -> dict[str, dict[str, Any]]:
        """Attributes of every complete step, by step id."""
        return {rec.step_id: rec.attrs for rec in _complete_steps(self.file)}

    def steps(self, procedure: str | None = None) -> list[StepRecord]:
        """Complete steps so far, optionally of one procedure kind."""
        return [s for s in _complete_steps(self.file) if procedure is None or s.attrs.get("procedure") == procedure]

    def discard_incomplete(self) -> list[str]:
        """Delete every step that is not complete (or unreadable); returns their ids."""
        steps = self.file["steps"]
        dropped = []
        for step_id in list(steps.keys()):
            try:
                ok = bool(steps[step_id].attrs.get("complete", False))
            except (KeyError, OSError, RuntimeError):
                ok = False
            if not ok:
                del steps[step_id]
                dropped.append(step_id)
        if dropped:
            _fsync(self.file)
        return dropped

    def set_status(self, status: str, reason: str = "") -> None:
        if status not in STATUSES:
            raise ValueError(status)
        self.file.attrs["status"] = status
        self.file.attrs["status_reason"] = reason
        _fsync(self.file)

    # ------------------------------------------------------------------ steps
    def begin_step(self, step: Step, stage_position_mm: float | None) -> StepWriter:
        """Create the step's group and datasets, marked incomplete; DiskSpaceLow (before anything
        is written) if the disk has no room for the step's raw size."""
        camera = self.camera_info()
        ensure_free(self.path, step.frames * frame_bytes(camera.width, camera.height, camera.confidence_dtype),
                    f"step {step.step_id} ({step.frames} frames)")
        steps = self.file["steps"]
        if step.step_id in steps:
            del steps[step.step_id]
        g = steps.create_group(step.step_id)
        g.attrs.update(
            complete=False,
            procedure=step.procedure,
            index=step.index,
            target=step.target,
            target_json=json.dumps(dict(step.target_params)),
            frames=step.frames,
            distance_mm=_nan_if_none(step.distance_mm),
            stage_position_mm=_nan_if_none(stage_position_mm),
            robot_angle_deg=_nan_if_none(step.robot_angle_deg),
            robot_radius_mm=_nan_if_none(step.robot_radius_mm),
            started=now_iso(),
        )
        n, h, w = step.frames, camera.height, camera.width
        compression = self.compression
        for name in CHANNELS:
            dtype = camera.confidence_dtype if name == "confidence" else "float32"
            if compression == "none":
                g.create_dataset(
                    name, shape=(n, h, w), dtype=dtype, chunks=(1, h, w),
                    dcpl=_early_alloc_dcpl(), fill_time="never",
                )
            else:
                g.create_dataset(name, shape=(n, h, w), dtype=dtype, chunks=(1, h, w),
                                 **codecs.dataset_options(compression))
        g.create_dataset("timestamp", shape=(n,), dtype="float64", dcpl=_early_alloc_dcpl(), fill_time="never")
        _fsync(self.file)
        return StepWriter(self, g, step, camera)

    def close(self) -> None:
        if self.file.id.valid:
            self.file.close()


# ---------------------------------------------------------------------- reading
@dataclass(frozen=True)
class StepRecord:
    """A complete step of a run file; arrays are read on demand."""

    step_id: str
    attrs: dict[str, Any]
    group: h5py.Group

    def read(self, channel: str, out: np.ndarray | None = None) -> np.ndarray:
        """The whole (N, H, W) stack of one channel (or (N,) timestamps).

        ``out``: a buffer of the same shape and dtype to read into (reused
        across steps, it saves allocating and page-faulting every stack).
        """
        dataset = self.group[channel]
        if out is not None and out.shape == dataset.shape and out.dtype == dataset.dtype:
            dataset.read_direct(out)
            return out
        return dataset[()]

    def frame(self, channel: str, k: int) -> np.ndarray:
        return self.group[channel][k]

    @property
    def settings(self) -> dict[str, Any]:
        return json.loads(self.attrs.get("settings_json", "{}"))


def _attrs(obj: h5py.HLObject) -> dict[str, Any]:
    out = {}
    for key, value in obj.attrs.items():
        if isinstance(value, bytes):
            value = value.decode()
        elif isinstance(value, np.generic):
            value = value.item()
        out[key] = value
    return out


def _check_format(f: h5py.File, path: Path) -> None:
    fmt = f.attrs.get("format")
    if fmt != FORMAT:
        raise InputError(f"{path} is not a labctl run file (format attribute is {fmt!r}, expected {FORMAT!r})")
    version = int(f.attrs.get("format_version", -1))
    if version != FORMAT_VERSION:
        raise InputError(f"{path} has run-file format version {version}; this labctl reads version {FORMAT_VERSION}")


def _camera_info(f: h5py.File) -> CameraInfo:
    a = f["camera"].attrs
    return CameraInfo(
        width=int(a["width"]), height=int(a["height"]),
        fov_deg=tuple(float(v) for v in a["fov_deg"]),  # type: ignore[arg-type]
        pixel_pitch_um=float(a["pixel_pitch_um"]), frame_rate_hz=float(a["frame_rate_hz"]),
        wavelength_nm=float(a["wavelength_nm"]),
        confidence_dtype=str(a.get("confidence_dtype", "float32")),
    )


def _complete_steps(f: h5py.File) -> Iterator[StepRecord]:
    steps = f["steps"]
    for step_id in sorted(steps.keys()):
        try:
            group = steps[step_id]
            attrs = _attrs(group)
        except (KeyError, OSError, RuntimeError):
            continue
        if attrs.get("complete", False):
            yield StepRecord(step_id, attrs, group)


class RunReader:
    """Read-only view of a run file, for evaluation and export."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(f"run file {self.path} does not exist")
        try:
            self.file = h5py.File(self.path, "r")
        except OSError as exc:
            raise InputError(not_a_run_file(self.path) or f"{self.path} is an HDF5 file that cannot be opened "
                             f"(is a run still writing it, or is it damaged?): {exc}") from None
        try:
            _check_format(self.file, self.path)
        except InputError:
            self.file.close()
            raise
        self.attrs = _attrs(self.file)
        self.camera = _camera_info(self.file)
        self.camera_attrs = _attrs(self.file["camera"])
        self.devices = {role: _attrs(g) for role, g in self.file.get("devices", {}).items()}

    def steps(self, procedure: str | None = None) -> list[StepRecord]:
        """Complete steps in execution order, optionally of one procedure kind."""
        return [s for s in _complete_steps(self.file) if procedure is None or s.attrs.get("procedure") == procedure]

    def step(self, step_id: str) -> StepRecord:
        for rec in _complete_steps(self.file):
            if rec.step_id == step_id:
                return rec
        raise InputError(f"{self.path} has no complete step {step_id!r}")

    def close(self) -> None:
        if self.file.id.valid:
            self.file.close()

    def __enter__(self) -> RunReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def existing_output_advice(path: Path) -> str:
    """Why a new run cannot be written to the existing ``path``, and what to do instead."""
    try:
        with RunReader(path) as reader:
            status = reader.attrs.get("status")
    except InputError:
        return f"{path} already exists and is not a labctl run file; choose another -o"
    if status == "complete":
        return (f"{path} already exists and is a complete run; evaluate it with 'labctl evaluate {path} -o DIR', "
                "or choose another -o for a new run")
    return f"{path} already exists (a run that is {status}); continue it with 'labctl resume {path}' or choose another -o"
