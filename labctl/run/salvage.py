"""Damaged run files: what can be recovered, and carrying the complete steps into a new file.

A run file is damaged when HDF5 cannot open it, or cannot change it in place: cut short (a copy
or a disk that failed), a flush that only partly reached the disk (kill -9 or an I/O error in
the middle of one), garbage written over it. ``labctl resume DAMAGED`` then says what can be
recovered and ``labctl resume DAMAGED --into NEW.h5`` copies the header and every complete step
whose data read back whole into NEW (written aside and renamed into place, like a new run), and
the run continues there. DAMAGED itself is only read.

Steps are found through the list of steps (``/steps``) and through the step index (``/step_index``),
which reaches each committed step's group by its address: HDF5 rewrites the list of steps in place at
every flush that adds a step, so a flush cut short can leave the list unreadable, while the index
changes only by an 8-byte data write at a fixed address and the groups it points to never change after
their commit. Files written before the index existed have only the list.
"""

from __future__ import annotations

import io
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py

from labctl.errors import InputError
from labctl.run import compression as codecs
from labctl.run.store import CHANNELS, FORMAT, STEP_INDEX, create_step_index, refuse_existing_output

READ_ERRORS = (OSError, KeyError, RuntimeError, ValueError, TypeError)
"""What h5py raises on damaged structures: OSError (HDF5 errors, "addr overflow", "truncated file"),
KeyError (a link to an object that cannot be read), RuntimeError / ValueError / TypeError (bad values)."""


@dataclass
class Salvage:
    """What a damaged run file still holds."""

    path: Path
    header: str | None = None
    """Why the header (format, campaign, camera, devices) cannot be read; None when it can."""
    index: str | None = None
    """Why the list of steps cannot be read (a flush that added a step cut short); None when it can."""
    complete: list[str] = field(default_factory=list)
    """Complete steps whose every dataset reads back whole."""
    lost: dict[str, str] = field(default_factory=dict)
    """Steps marked complete that cannot be read, with the reason; they run again."""

    def summary(self) -> str:
        """One paragraph for the operator."""
        if self.header is not None:
            return f"nothing can be recovered from {self.path}: its header cannot be read ({self.header})"
        if self.index is not None and not self.complete:
            return (f"its list of steps cannot be read ({self.index}): no step can be recovered, the campaign, "
                    "devices, camera and simulation can; in a new file the run starts over")
        text = f"{len(self.complete)} complete step(s) can be recovered"
        if self.index is not None:
            text = f"its list of steps cannot be read ({self.index}); from the step index, " + text
        if self.complete:
            text += f" ({self.complete[0]} .. {self.complete[-1]})"
        if self.lost:
            text += "; unreadable, to be run again: " + ", ".join(f"{k} ({v})" for k, v in self.lost.items())
        return text


class _ZeroExtended(io.RawIOBase):
    """A run file cut short, read as if it had the length its superblock records, zeros past the cut
    (HDF5 refuses to open a file shorter than that); :func:`_step_readable` rejects every chunk past the cut."""

    def __init__(self, path: Path, length: int) -> None:
        super().__init__()
        self._file = open(path, "rb")  # noqa: SIM115 (closed with this object)
        self.cut = os.fstat(self._file.fileno()).st_size
        self._length, self._position = max(length, self.cut), 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._position, io.SEEK_END: self._length}[whence]
        self._position = base + offset
        return self._position

    def tell(self) -> int:
        return self._position

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        n = max(0, min(len(view), self._length - self._position))
        self._file.seek(self._position)
        got = self._file.readinto(view[:n]) or 0
        view[got:n] = bytes(n - got)
        self._position += n
        return n

    def close(self) -> None:
        self._file.close()
        super().close()


_STORED_EOF = re.compile(r"truncated file: eof = (\d+).*stored_eof = (\d+)")


def _open(path: Path) -> tuple[h5py.File, int]:
    """``path`` opened read-only, and the length up to which its bytes are real (short of it, zeros)."""
    try:
        return h5py.File(path, "r"), os.path.getsize(path)
    except OSError as exc:
        match = _STORED_EOF.search(str(exc))
        if match is None:
            raise
        reader = _ZeroExtended(path, int(match.group(2)))
        return h5py.File(reader, "r"), reader.cut


def _first_line(exc: BaseException) -> str:
    return (str(exc).splitlines() or [type(exc).__name__])[0]


def _read_header(f: h5py.File) -> None:
    """Raise if the attributes and groups that resume needs cannot be read."""
    if f.attrs.get("format") != FORMAT:
        raise ValueError(f"format attribute is {f.attrs.get('format')!r}, expected {FORMAT!r}")
    for name in ("campaign_toml", "format_version"):
        f.attrs[name]
    dict(f["camera"].attrs)
    for group in f.get("devices", {}).values():
        dict(group.attrs)
    if "sim" in f:
        dict(f["sim"].attrs)


def _step_readable(group: h5py.Group, cut: int) -> None:
    """Read every dataset of a step whole (decompressing every chunk); raise if any part is damaged or
    lies past ``cut``, the end of the file's real bytes."""
    for name in (*CHANNELS, "timestamp"):
        dataset = group[name]
        if dataset.chunks is None:
            extents = [(dataset.id.get_offset() or 0, dataset.id.get_storage_size())]
        else:
            extents = [(c.byte_offset, c.size) for c in map(dataset.id.get_chunk_info, range(dataset.id.get_num_chunks()))]
        if any(offset + size > cut for offset, size in extents):
            raise ValueError(f"{name} lies past the end of the file (cut at byte {cut})")
        dataset[()]


def _indexed_steps(f: h5py.File) -> dict[str, h5py.Group]:
    """The step groups the step index points to, by step id (``<NNNNN>_<procedure>``, from the group's own
    attributes); elements that are null or do not lead to step i's group are left out."""
    found: dict[str, h5py.Group] = {}
    try:
        refs = f[STEP_INDEX][()] if STEP_INDEX in f else []
    except READ_ERRORS:
        return found
    for i, ref in enumerate(refs):
        if not ref:
            continue
        try:
            group = f[ref]
            if not isinstance(group, h5py.Group) or int(group.attrs["index"]) != i:
                continue
            procedure = group.attrs["procedure"]
            procedure = procedure.decode() if isinstance(procedure, bytes) else str(procedure)
        except READ_ERRORS:
            continue
        found[f"{i:05d}_{procedure}"] = group
    return found


def _locate_steps(f: h5py.File) -> tuple[dict[str, h5py.Group], str | None]:
    """Every step group the file leads to (through the list of steps and the step index), by step id, and
    why the list of steps cannot be read (None when it can)."""
    groups = _indexed_steps(f)
    try:
        listed = f["steps"]
        ids = list(listed.keys())
    except READ_ERRORS as exc:
        return dict(sorted(groups.items())), _first_line(exc)
    for step_id in ids:
        try:
            group = listed[step_id]
        except READ_ERRORS:
            continue
        indexed = groups.get(step_id)
        if indexed is None or not _complete(indexed) or _complete(group):
            groups[step_id] = group
    return dict(sorted(groups.items())), None


def _complete(group: h5py.Group) -> bool:
    try:
        return bool(group.attrs.get("complete", False))
    except READ_ERRORS:
        return False


def inspect(path: Path) -> Salvage:
    """Read ``path`` (read-only) and report its readable header and complete steps."""
    salvage = Salvage(path)
    try:
        f, cut = _open(path)
    except READ_ERRORS as exc:
        salvage.header = _first_line(exc)
        return salvage
    with f:
        try:
            _read_header(f)
        except READ_ERRORS as exc:
            salvage.header = _first_line(exc)
            return salvage
        groups, salvage.index = _locate_steps(f)
        for step_id, group in groups.items():
            try:
                if not bool(group.attrs.get("complete", False)):
                    continue
                _step_readable(group, cut)
            except READ_ERRORS as exc:
                salvage.lost[step_id] = _first_line(exc)
                continue
            salvage.complete.append(step_id)
    return salvage


def carry_over(source: Path, target: Path, report: Callable[[str], None]) -> Salvage:
    """Write ``target``: ``source``'s header and its readable complete steps, status ``aborted``.

    InputError when ``target`` exists or nothing can be recovered. ``source`` is only read."""
    refuse_existing_output(target)
    salvage = inspect(source)
    if salvage.header is not None:
        raise InputError(salvage.summary())
    tmp = target.with_name(f".{target.name}.creating")
    try:
        src, _ = _open(source)
        with src, h5py.File(tmp, "w") as dst:
            for key in src.attrs.keys():
                try:
                    dst.attrs[key] = src.attrs[key]
                except READ_ERRORS:  # e.g. a status whose flush was cut short: set below
                    continue
            dst.attrs["status"] = "aborted"
            dst.attrs["status_reason"] = f"recovered from the damaged run file {source}"
            for name in ("devices", "camera", "sim"):
                if name in src:
                    src.copy(src[name], dst, name=name)
            steps = dst.create_group("steps")
            length = _index_length(src)
            if length is not None:
                create_step_index(dst, length)
            compression = str(src.attrs.get("compression", "none"))
            groups, _ = _locate_steps(src)
            for step_id in salvage.complete:
                copy = steps.create_group(step_id)
                _copy_step(groups[step_id], copy, compression)
                if length is not None and 0 <= int(copy.attrs["index"]) < length:
                    dst[STEP_INDEX][int(copy.attrs["index"])] = copy.ref
                report(f"recovered {step_id}")
            dst.flush()
            os.fsync(dst.id.get_vfd_handle())
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return salvage


def _index_length(f: h5py.File) -> int | None:
    """The length of the file's step index; None when it has none (written before it existed) or it cannot be read."""
    try:
        return int(f[STEP_INDEX].shape[0]) if STEP_INDEX in f else None
    except READ_ERRORS:
        return None


def _copy_step(src: h5py.Group, dst: h5py.Group, compression: str) -> None:
    """The step's attributes and data, stored as a new step would be (labctl.run.store)."""
    for name in (*CHANNELS, "timestamp"):
        data = src[name][()]
        if name == "timestamp" or compression not in codecs.COMPRESSIONS or compression == "none":
            dst.create_dataset(name, data=data, chunks=src[name].chunks)
        else:
            dst.create_dataset(name, data=data, chunks=src[name].chunks, **codecs.dataset_options(compression))
    for key, value in src.attrs.items():
        if key != "complete":
            dst.attrs[key] = value
    dst.attrs["complete"] = True

