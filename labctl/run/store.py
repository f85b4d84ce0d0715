"""The HDF5 run file (docs/runfile.md): layout, crash-safe writing, reading.

Crash safety. A run file must stay readable whatever happens (kill -9, power
loss during a stack, a full disk, a failing disk); HDF5's flushes are not atomic,
so a kill inside one can damage the file, which labctl.run.salvage recovers.
The writer therefore

* creates the file under a temporary name and renames it into place, so the
  path either does not exist or holds a valid file;
* creates a step's group and datasets, then flushes, before the first frame;
* stores one frame per chunk, written whole with HDF5's direct chunk write: compressed
  losslessly by default, in worker threads beside the capture and written in order
  (labctl.run.compression, labctl.run.chunks; ``compression = "none"``: allocated at
  creation, ``ALLOC_TIME_EARLY``, and written as raw chunks); the metadata cache never
  evicts while the file is open, so HDF5 metadata reaches the disk only at the flushes
  below, and a crash between them leaves the file as it was at the last one;
* checks before each step that the disk has room for it (labctl.run.diskspace), and
  then reserves the step's worst-case size in the file (fallocate, the file's length
  unchanged), so no write inside the step can meet a full disk even when another
  process takes the free space meanwhile: the disk filling becomes DiskSpaceLow
  before the step writes anything, and the file stays as its last flush left it;
* writes the step's attributes at the end, after every frame's chunk, ``complete = True``
  last, then records the step's group in the step index (``/step_index``), then flushes
  and fsyncs.

Why a step index. HDF5 keeps ``/steps``'s links in an old-style symbol table (local
heap, B-tree, symbol-table nodes) and rewrites it in place when a step is added,
in the same flush as the blocks it now points to (a grown heap, a split node): a
kill inside that flush can leave the list pointing past the end of the file. The
index is a contiguous dataset of object references (group addresses) allocated
when the file is created, so recording a step is an 8-byte data write at a fixed
address (one pwrite of the dataset at the flush; no metadata moves), and the
groups it points to never change after their commit: labctl.run.salvage reaches
the committed steps through it when the list is unreadable. Keeping the table
itself in place (H5Pset_sym_k, a local-heap size hint, pre-sized new-style link
storage) is not reachable from h5py, would still rewrite several blocks per
flush, and needs the largest number of steps fixed at creation. Files written
before the index existed have none and are read and resumed as before.

The run's status attributes are created with the file and changed in place
(``attrs.modify``, HDF5's attribute write): the root's object header never grows
into a new block, so a kill in a status flush can leave the new status unreadable
(the file then counts as damaged; resume --into continues it), never the root.

Why reserve rather than recover: HDF5 cannot take back a failed write. With a
write failed, the next flush writes part of the dirty metadata (in-place updates
succeed, appended ones fail), leaving committed structures pointing past the end
of the file ("addr overflow" on the next change), and a file whose flush failed
at close is left half torn down in the library: releasing one of its dataset
handles afterwards crashed the process (SIGSEGV in H5D_close). Writing each step
to a file of its own and copying it in would double the I/O of every step. So a
full disk is kept away from HDF5, and for a write error that no reservation
prevents (EIO) the handle is detached (:func:`_detach`): its descriptor is
pointed at a scratch memory file, so the library's flush and close complete
there and nothing more reaches the run file; it is then opened anew to be marked
aborted.

A step without ``complete = True`` is unfinished and is discarded by resume; a
file HDF5 cannot open or change (DamagedRunFile) is recovered by
labctl.run.salvage.
"""

from __future__ import annotations

import errno
import json
import math
import os
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from drivers.protocols import CameraInfo, DeviceIdentity, Frame
from labctl.errors import InputError
from labctl.provenance import labctl_version, now_iso
from labctl.run import compression as codecs
from labctl.run.chunk_read import read_stack
from labctl.run.chunks import ChunkWriter, CompressionFailed
from labctl.run.diskspace import DiskSpaceLow, ensure_free, frame_bytes, mount_point, release, reserve
from labctl.run.filekind import describe, is_binary_data, not_a_run_file
from procedures.steps import Step

FORMAT = "labctl-run"
FORMAT_VERSION = 1
CHANNELS = ("x", "y", "z", "intensity", "confidence")
STATUSES = ("running", "complete", "aborted")
METADATA_ALLOWANCE = 2**20
"""Bytes reserved beyond a step's worst-case frame data, and before a status change, for HDF5 metadata
(object headers, attributes, group and chunk indices; a 10-step file of 100 frames each holds about 0.2 MB)."""
STEP_INDEX = "step_index"
"""Root dataset: element i holds an object reference to step i's group once the step is committed (docs/runfile.md)."""
CHUNK_OVERHEAD = 16 + 64
"""Worst-case bytes a compressed chunk takes beyond its raw size (Blosc's header, BLOSC_MAX_OVERHEAD = 16)
plus its share of the chunk index."""

#: where a run that keeps no frames in its file hands each committed step (:attr:`RunWriter.frame_sink`): the
#: step's record, and a function giving a channel's (N, H, W) stack as it was recorded
FrameSink = Callable[["StepRecord", Callable[[str], np.ndarray]], None]
#: the root attribute of a run file whose frames went to a frame sink: False (absent: the file keeps its frames)
FRAMES_KEPT = "frames_kept"


class DamagedRunFile(InputError):
    """HDF5 cannot open the run file, or cannot change it in place (labctl.run.salvage recovers what it can)."""


_NOT_DAMAGE = (errno.EACCES, errno.EPERM, errno.EAGAIN, errno.ENOENT, errno.EISDIR, errno.EROFS)


class RunFileError(OSError):
    """A write to the run file failed (an I/O error, or no space where nothing could be reserved). The open
    handle is then detached from the file, so nothing more reaches it: the file keeps its last flushed state."""


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

    def __init__(self, run: RunWriter, group: h5py.Group, step: Step, camera: CameraInfo, held: bool) -> None:
        self.run = run
        self.group = group
        self.step = step
        self.shape = (camera.height, camera.width)
        self.confidence_dtype = np.dtype(camera.confidence_dtype)
        self._datasets = {name: group[name] for name in CHANNELS}
        self._timestamps = group["timestamp"]
        self._chunks = run.chunk_writer()
        #: the frames by channel, where the run hands them to its frame sink instead of the file
        self._held: dict[str, dict[int, np.ndarray]] | None = {name: {} for name in CHANNELS} if held else None

    def write(self, k: int, frame: Frame) -> None:
        """Store frame ``k`` of the stack; FrameError if its arrays do not fit, RunFileError if the write fails,
        CompressionFailed if compressing this or an earlier frame failed. Compressed frames are written in the
        background: their arrays must stay unchanged until the step is committed."""
        if not 0 <= k < self.step.frames:
            raise FrameError(f"frame index {k} outside 0..{self.step.frames - 1}")
        with self.run.guarded(f"frame {k} of step {self.step.step_id}"):
            self._write(k, frame)

    def _write(self, k: int, frame: Frame) -> None:
        for name in CHANNELS:
            array = np.asarray(getattr(frame, name))
            if array.shape != self.shape:
                raise FrameError(f"frame {k}: {name} has shape {array.shape}, expected {self.shape}")
            dtype = self.confidence_dtype if name == "confidence" else np.float32
            data = np.ascontiguousarray(array, dtype=dtype)
            dataset = self._datasets[name].id
            if self._held is not None:  # the arrays as written, kept by reference until the commit
                self._held[name][k] = data
            elif self._chunks is None:  # one frame is exactly one uncompressed chunk: no selection or filter machinery
                dataset.write_direct_chunk((k, 0, 0), data)
            else:
                self._chunks.put(dataset, (k, 0, 0), data, f"frame {k}'s {name} of step {self.step.step_id}")
        self._timestamps[k] = float(frame.timestamp)

    def stack(self, channel: str) -> np.ndarray:
        """The (N, H, W) stack of ``channel`` as written so far (every frame given to :meth:`write` included)."""
        if self._held is not None:
            return self._held_stack(channel)
        with self.run.guarded(f"the frames of step {self.step.step_id}"):
            self._write_queued()
        return self.group[channel][()]

    def _held_stack(self, channel: str) -> np.ndarray:
        """A held channel's (N, H, W) stack, zero where no frame was given (as the file's fill value reads)."""
        assert self._held is not None
        stack = np.zeros((self.step.frames, *self.shape), self._datasets[channel].dtype)
        for k, data in self._held[channel].items():
            stack[k] = data
        return stack

    def _write_queued(self) -> None:
        if self._chunks is not None:
            self._chunks.drain()

    def commit(self, attrs: Mapping[str, Any]) -> None:
        """Write the frames still queued, then the step's attributes, ``complete = True`` last, and make it
        durable (CompressionFailed, nothing committed, if a frame could not be compressed); then give back the
        space reserved for the step that it did not take."""
        with self.run.guarded(f"committing step {self.step.step_id}"):
            self._write_queued()
            for key, value in attrs.items():
                self.group.attrs[key] = value
            self.group.attrs["finished"] = now_iso()
            self.group.attrs["complete"] = True
            steps, default = self.group.parent, self.group.parent.attrs.get("default")
            if not (isinstance(default, str) and default in steps):  # a NeXus viewer shows the first complete step
                steps.attrs["default"] = self.step.step_id
            self.run.index_step(self.step.index, self.group)
            self.run.make_durable()
            release(self.run.file.id.get_vfd_handle())
        if self.run.frame_sink is not None:
            stack = self._held_stack if self._held is not None else self.stack
            try:
                self.run.frame_sink(StepRecord(self.step.step_id, _attrs(self.group), self.group), stack)
            finally:
                self._held = None if self._held is None else {name: {} for name in CHANNELS}


#: NeXus description of a step's datasets (NXdata base class): (units, long_name)
NEXUS_FIELDS = {
    "z": ("mm", "z, depth along the optical axis (mm)"),
    "x": ("mm", "x, right in the camera frame (mm)"),
    "y": ("mm", "y, down in the camera frame (mm)"),
    "intensity": ("counts", "intensity (amplitude or IR image, camera units)"),
    "confidence": ("counts", "confidence (camera units)"),
    "timestamp": ("s", "frame time (s, the camera's clock)"),
}


def _nexus_step(group: h5py.Group) -> None:
    """Mark a step as a NeXus NXdata group, so that NeXus viewers (silx view, h5web) show it by itself: its z
    stack as the signal (an image per frame, frames along ``timestamp``), the other channels as auxiliary
    signals, ``units`` and ``long_name`` on every dataset."""
    group.attrs.update(NX_class="NXdata", signal="z", auxiliary_signals=["intensity", "x", "y", "confidence"],
                       axes=["timestamp", ".", "."])
    for name, (units, long_name) in NEXUS_FIELDS.items():
        group[name].attrs.update(units=units, long_name=long_name)
        if name != "timestamp":
            group[name].attrs["interpretation"] = "image"


class RunWriter:
    """An open run file that steps are appended to."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        refuse_what_is_not_hdf5(self.path)
        try:
            self.file = h5py.File(self.path, "r+")
        except OSError as exc:
            if exc.errno in _NOT_DAMAGE or "unable to lock file" in str(exc):
                raise InputError(f"cannot open run file {self.path} for writing: {exc}") from None
            raise DamagedRunFile(f"HDF5 cannot open it: {str(exc).splitlines()[0]}") from None
        try:
            _check_format(self.file, self.path)
            dict(self.file.attrs)  # a status cut short by a kill in its flush: its new value never reached the disk
            self.file["steps"].keys()
        except (OSError, KeyError, RuntimeError, ValueError) as exc:
            self.file.close()
            raise DamagedRunFile(f"its header cannot be read: {str(exc).splitlines()[0]}") from None
        except InputError:
            self.file.close()
            raise
        _keep_metadata_until_flush(self.file)
        self.failure: str | None = None
        self._chunks: ChunkWriter | None = None
        #: None: frames are stored in the file. Otherwise the file keeps each step's metadata and timestamps
        #: only, and each committed step's frames go to this sink (a null replica, observed as it is made:
        #: labctl/reconcile/null.py), so that nothing of them reaches the disk
        self.frame_sink: FrameSink | None = None

    def hand_frames_to(self, sink: FrameSink) -> None:
        """From now on the file keeps no frames: each committed step's go to ``sink`` (:attr:`frame_sink`). The
        file says so in its ``frames_kept`` attribute, and :class:`RunReader` refuses it."""
        with self.guarded("marking the run file as keeping no frames"):
            self.file.attrs[FRAMES_KEPT] = False
        self.frame_sink = sink

    def make_durable(self) -> None:
        """Flush the file and fsync it; a file whose frames go to a frame sink is only flushed (it holds no frames
        to keep, and is deleted after: a null replica's fsync of every step cost seconds)."""
        if self.frame_sink is None:
            _fsync(self.file)
        else:
            self.file.flush()

    def chunk_writer(self) -> ChunkWriter | None:
        """The compression threads of this file's frames (started on first use), None for ``compression = "none"``."""
        if self.compression == "none":
            return None
        if self._chunks is None:
            self._chunks = ChunkWriter(self.compression)
        return self._chunks

    def _drop_queued_chunks(self) -> None:
        if self._chunks is not None:
            self._chunks.discard()

    def index_step(self, index: int, group: h5py.Group) -> None:
        """Record ``group`` as step ``index`` in the step index (files written before it existed have none):
        a raw-data write of 8 bytes at a fixed address, no HDF5 metadata changes."""
        index_dataset = self.file.get(STEP_INDEX)
        if index_dataset is not None and 0 <= index < index_dataset.shape[0]:
            index_dataset[index] = group.ref

    # ------------------------------------------------------------------ faults
    @contextmanager
    def guarded(self, what: str) -> Iterator[None]:
        """HDF5 writes for ``what``: an OSError or RuntimeError from them (EIO, ENOSPC) detaches the handle from the file
        (:func:`_detach`) and becomes a RunFileError naming the file system."""
        if self.failure is not None:
            raise RunFileError(f"{self.path} is detached after an earlier write error ({self.failure})")
        try:
            yield
        except (DiskSpaceLow, CompressionFailed):
            raise
        except (OSError, RuntimeError) as exc:  # h5py raises RuntimeError for some failed flushes
            self._drop_queued_chunks()
            self.failure = str(getattr(exc, "strerror", None) or exc).splitlines()[0]
            cause = _errno_text(exc)
            _detach(self.file)
            raise RunFileError(
                f"writing {what} to {self.path} failed ({cause}) on the file system mounted at "
                f"{mount_point(self.path.parent)}; the file keeps every step completed before it"
            ) from None

    def _reserve(self, nbytes: int, what: str) -> None:
        """Allocate ``nbytes`` past the file's current end (DiskSpaceLow when the file system has no room),
        so the HDF5 writes that follow cannot meet a full disk."""
        handle = self.file.id.get_vfd_handle()
        end = max(os.fstat(handle).st_size, self.file.id.get_filesize()) + nbytes
        reserve(handle, self.path, end, what)

    def _reopen(self) -> None:
        """After a write error: open the file again as the disk holds it (its last flushed state)."""
        self._drop_queued_chunks()
        self.file = h5py.File(self.path, "r+")
        _keep_metadata_until_flush(self.file)
        self.failure = None

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
        steps: int,
        sim: tuple[str, int] | None = None,
        compression: str = codecs.DEFAULT,
    ) -> RunWriter:
        """Create a new run file (atomically: written aside, then renamed into place) for a campaign of
        ``steps`` steps; frames are stored with ``compression`` (one of labctl.run.compression.COMPRESSIONS)."""
        path = Path(path)
        codecs.dataset_options(compression)  # an unknown name fails before anything is written
        refuse_existing_output(path)
        tmp = path.with_name(f".{path.name}.creating")
        with h5py.File(tmp, "w") as f:
            f.attrs.update(
                format=FORMAT,
                format_version=FORMAT_VERSION,
                labctl_version=labctl_version(),
                created=now_iso(),
                campaign_toml=campaign_toml,
                status="running",
                status_reason="",
                simulated=bool(simulated),
                compression=compression,
                how_to_read=codecs.how_to_read(compression),
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
            f.attrs.update(NX_class="NXroot", default="steps")  # NeXus: viewers follow @default to a step
            f.create_group("steps").attrs["NX_class"] = "NXentry"
            create_step_index(f, steps)
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
        """Delete every step that is not complete (or unreadable); returns their ids. DamagedRunFile when
        the file's structure does not allow it (the file is then left as it was on disk)."""
        try:
            return self._discard_incomplete()
        except DiskSpaceLow:
            raise
        except (OSError, KeyError, RuntimeError, ValueError) as exc:
            _detach(self.file)
            self.failure = str(exc).splitlines()[0]
            raise DamagedRunFile(f"its unfinished steps cannot be removed: {self.failure}") from None

    def _discard_incomplete(self) -> list[str]:
        steps = self.file["steps"]
        dropped = []
        for step_id in list(steps.keys()):
            try:
                ok = bool(steps[step_id].attrs.get("complete", False))
            except (KeyError, OSError, RuntimeError):
                ok = False
            if not ok:
                dropped.append(step_id)
        if dropped:
            self._reserve(METADATA_ALLOWANCE, "discarding unfinished steps")
            with self.guarded("discarding unfinished steps"):
                for step_id in dropped:
                    del steps[step_id]
                _fsync(self.file)
        return dropped

    def set_status(self, status: str, reason: str = "") -> None:
        """Record the run's status (durably). After a write error the file is opened again first, so an
        aborted run is marked aborted whenever the disk still takes a write."""
        if status not in STATUSES:
            raise ValueError(status)
        if self.failure is not None:
            self._reopen()
        self._reserve(METADATA_ALLOWANCE, f"marking the run {status}")
        with self.guarded(f"status {status}"):
            self.file.attrs.modify("status", status)  # in place (H5Awrite): the root's object header does not grow
            self.file.attrs.modify("status_reason", reason)
            _fsync(self.file)

    # ------------------------------------------------------------------ steps
    def begin_step(self, step: Step, stage_position_mm: float | None, read_back: bool = False) -> StepWriter:
        """Create the step's group and datasets, marked incomplete; DiskSpaceLow (before anything
        is written) if the disk has no room for the step's raw size, or cannot reserve its worst-case size.
        ``read_back``: the run reads the step's frames from the file later, so the file keeps them even where
        its frames go to a frame sink (:meth:`hand_frames_to`; the sink then has them as well)."""
        camera = self.camera_info()
        what = f"step {step.step_id} ({step.frames} frames)"
        raw = step.frames * frame_bytes(camera.width, camera.height, camera.confidence_dtype)
        self._drop_queued_chunks()  # of a step begun before and abandoned
        held = self.frame_sink is not None and not read_back
        if not held:
            ensure_free(self.path, raw, what)
        chunks = step.frames * (len(CHANNELS) + 1)
        frames = 0 if held else raw + chunks * CHUNK_OVERHEAD
        self._reserve(frames + 8 * step.frames + METADATA_ALLOWANCE, what)
        with self.guarded(f"the start of step {step.step_id}"):
            return self._create_step(step, stage_position_mm, camera, held)

    def _create_step(self, step: Step, stage_position_mm: float | None, camera: CameraInfo,
                     held: bool) -> StepWriter:
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
            if held:  # never written: no chunk is allocated
                g.create_dataset(name, shape=(n, h, w), dtype=dtype, chunks=(1, h, w))
            elif compression == "none":
                g.create_dataset(
                    name, shape=(n, h, w), dtype=dtype, chunks=(1, h, w),
                    dcpl=_early_alloc_dcpl(), fill_time="never",
                )
            else:
                g.create_dataset(name, shape=(n, h, w), dtype=dtype, chunks=(1, h, w),
                                 **codecs.dataset_options(compression))
        g.create_dataset("timestamp", shape=(n,), dtype="float64", dcpl=_early_alloc_dcpl(), fill_time="never")
        _nexus_step(g)
        self.make_durable()
        return StepWriter(self, g, step, camera, held)

    def close(self) -> None:
        """Stop the compression threads (chunks still queued are dropped: their step is not committed) and
        close the file; after a write error (the handle is detached) this writes nothing."""
        try:
            if self._chunks is not None:
                self._chunks.close()
                self._chunks = None
        finally:
            if self.file.id.valid:
                with self.guarded("closing"):
                    self.file.close()


def create_step_index(f: h5py.File, steps: int) -> None:
    """The root dataset indexing ``steps`` steps by object reference, all null: contiguous and allocated
    (zero-filled) now, so that recording a step later writes only its element, at a fixed address."""
    dcpl = _early_alloc_dcpl()
    dcpl.set_fill_time(h5py.h5d.FILL_TIME_ALLOC)
    f.create_dataset(STEP_INDEX, shape=(steps,), dtype=h5py.ref_dtype, dcpl=dcpl)


def _errno_text(exc: OSError | RuntimeError) -> str:
    """``No space left on device`` for an OSError from HDF5, whose text buries errno in a long message."""
    number = getattr(exc, "errno", None)
    if number is None:
        for code in (errno.ENOSPC, errno.EIO, errno.EDQUOT, errno.EROFS):
            if f"errno = {code}," in str(exc):
                number = code
    return os.strerror(number) if number else str(exc).splitlines()[0]


def _detach(f: h5py.File) -> None:
    """Point the file's descriptor at an anonymous in-memory file (memfd_create(2)) and close it there.

    After a failed write HDF5 still holds dirty metadata; a flush into the run file would write part of it
    (damaging the committed steps), and closing a file whose flush failed leaves HDF5 half torn down (a
    later release of a dataset handle crashed the process with SIGSEGV). Written into the scratch file, the
    flush and close succeed and the run file keeps the state of its last successful flush."""
    try:
        handle = f.id.get_vfd_handle()
        scratch = os.memfd_create("labctl-detached-run-file")
        os.dup2(scratch, handle)
        os.close(scratch)
        f.close()
    except (OSError, RuntimeError, ValueError):
        pass


# ---------------------------------------------------------------------- reading
@dataclass(frozen=True)
class StepRecord:
    """A complete step of a run file; arrays are read on demand."""

    step_id: str
    attrs: dict[str, Any]
    group: h5py.Group

    def read(self, channel: str, out: np.ndarray | None = None, by_chunk: bool = False) -> np.ndarray:
        """The whole (N, H, W) stack of one channel (or (N,) timestamps).

        ``out``: a buffer of the same shape and dtype to read into (reused
        across steps, it saves allocating and page-faulting every stack).
        ``by_chunk``: each frame's chunk read as stored and decompressed by
        Blosc (:func:`labctl.run.chunk_read.read_stack`), else HDF5 reads.
        """
        dataset = self.group[channel]
        if by_chunk:
            if out is None or out.shape != dataset.shape or out.dtype != dataset.dtype:
                out = np.empty(dataset.shape, dataset.dtype)
            return read_stack(dataset, out)
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
    """The object's attributes as Python values; one whose value cannot be read (its flush cut short) is left out."""
    out = {}
    for key in obj.attrs.keys():
        try:
            value = obj.attrs[key]
        except (OSError, KeyError, RuntimeError, ValueError):
            continue
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
            what = "is not a regular file" if self.path.exists() else "does not exist"
            raise InputError(f"run file {self.path} {what}")
        try:
            self.file = h5py.File(self.path, "r")
        except OSError as exc:
            raise InputError(not_a_run_file(self.path) or f"{self.path} is an HDF5 file that cannot be opened "
                             f"(is a run still writing it, or is it damaged?): {exc}") from None
        try:
            _check_format(self.file, self.path)
            if not self.file.attrs.get(FRAMES_KEPT, True):
                raise InputError(f"{self.path} keeps no frames: they went to a reader as each step was made (as a "
                                 "reconcile's null replica's do), so there is nothing in it to evaluate")
        except InputError:
            self.file.close()
            raise
        self.attrs = _attrs(self.file)
        self.camera = _camera_info(self.file)
        self.camera_attrs = _attrs(self.file["camera"])
        self.devices = {role: _attrs(g) for role, g in self.file.get("devices", {}).items()}
        self._steps: list[StepRecord] | None = None

    def _complete(self) -> list[StepRecord]:
        """The complete steps, their attributes read once: the file is open read-only, so they cannot change
        (an evaluation asks for them once per procedure kind; reading 37 steps' attributes ten times took 0.4 s)."""
        if self._steps is None:
            self._steps = list(_complete_steps(self.file))
        return self._steps

    def steps(self, procedure: str | None = None) -> list[StepRecord]:
        """Complete steps in execution order, optionally of one procedure kind."""
        return [s for s in self._complete() if procedure is None or s.attrs.get("procedure") == procedure]

    def step(self, step_id: str) -> StepRecord:
        for rec in self._complete():
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


def refuse_existing_output(path: Path) -> None:
    """InputError when ``path`` exists: a new run is never written over a file. The message says what the file
    is and what to do instead (resume the run, evaluate it, or choose another -o)."""
    if path.exists():
        raise InputError(_existing_output_advice(path))


def refuse_what_is_not_hdf5(path: Path) -> None:
    """Refuse ``path`` as a run file before HDF5 opens it (opened for writing, it would be changed) when it is
    not HDF5 at all: DamagedRunFile when it holds other binary data (a run file whose header was overwritten),
    InputError naming what it is otherwise (empty, a text file)."""
    if (wrong := not_a_run_file(path)) is not None:
        if is_binary_data(path):
            raise DamagedRunFile(f"it is {describe(path)}: the HDF5 header is overwritten, or it was never a run file")
        raise InputError(wrong)


def _existing_output_advice(path: Path) -> str:
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
