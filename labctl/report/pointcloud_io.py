"""Point-cloud files: organized PCD v0.7 and PLY 1.0 (Thesis 2024, 6.7: for CloudCompare and Open3D).

PCD (Point Cloud Library file format v0.7): header ``VERSION``, ``FIELDS x y
z intensity``, ``SIZE 4 4 4 4``, ``TYPE F F F F``, ``COUNT 1 1 1 1``,
``WIDTH`` (columns), ``HEIGHT`` (rows; > 1 = organized), ``VIEWPOINT 0 0 0 1
0 0 0``, ``POINTS`` = WIDTH x HEIGHT, ``DATA binary|ascii``; points row by row,
invalid ones kept as NaN so the image structure survives. Binary data are
packed little-endian float32 records.

PLY (Stanford polygon format 1.0, ``binary_little_endian`` or ``ascii``): one
``vertex`` element with float ``x y z intensity``. PLY has no organization, so
only valid points are written and the organized size is recorded in a
``comment``.

Coordinates are millimetres in the camera frame (x right, y down, z along the
optical axis), as in the run file (docs/runfile.md).
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8",
              ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4", ("I", 8): "<i8"}
_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
_PLY_ORDER = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "<"}
_PLY_SIZE = re.compile(r"organized width (\d+) height (\d+)")


@dataclass(frozen=True)
class PointCloud:
    """Points as an (H, W, 3) array (NaN = invalid; H = 1 for an unorganized cloud) and their intensity (H, W)."""

    xyz: np.ndarray
    intensity: np.ndarray | None = None
    comments: tuple[str, ...] = ()

    @property
    def organized(self) -> bool:
        return self.xyz.shape[0] > 1

    @property
    def organized_size(self) -> tuple[int, int] | None:
        """(width, height) of the organized cloud a PLY file was written from, from its comment."""
        for comment in self.comments:
            found = _PLY_SIZE.search(comment)
            if found:
                return int(found.group(1)), int(found.group(2))
        return None


def _records(xyz: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
    """(H, W, 3) points and (H, W) intensity as float32 records x, y, z, intensity."""
    xyz = np.asarray(xyz)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise ValueError(f"points must be an (H, W, 3) array, got shape {xyz.shape}")
    if intensity is None:
        intensity = np.zeros(xyz.shape[:2], np.float32)
    intensity = np.asarray(intensity)
    if intensity.shape != xyz.shape[:2]:
        raise ValueError(f"intensity must be {xyz.shape[:2]}, got {intensity.shape}")
    records = np.empty(xyz.shape[:2], dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    for k, name in enumerate("xyz"):
        records[name] = xyz[..., k]
    records["intensity"] = intensity
    return records


def _ascii_rows(records: np.ndarray) -> bytes:
    """One line per record, 9 significant digits (float32 round trip), NaN as ``nan``."""
    table = np.column_stack([records[name].astype(np.float64) for name in records.dtype.names])
    out = io.BytesIO()
    np.savetxt(out, table, fmt="%.9g")
    return out.getvalue()


# ---------------------------------------------------------------------- PCD
def write_pcd(path: str | Path, xyz: np.ndarray, intensity: np.ndarray | None = None, *, binary: bool = True,
              comment: str = "") -> Path:
    """Write an organized cloud ((H, W, 3) mm, NaN = invalid) as a PCD v0.7 file, invalid points kept as NaN.

    ``comment``: one extra ``#`` header line (after the format line, where PCL
    and Open3D skip comments).
    """
    records = _records(xyz, intensity)
    height, width = records.shape
    lines = ["# .PCD v0.7 - Point Cloud Data file format"]
    if comment:
        lines.append("# " + " ".join(comment.split()))
    lines += [
        "VERSION 0.7",
        "FIELDS x y z intensity",
        "SIZE 4 4 4 4",
        "TYPE F F F F",
        "COUNT 1 1 1 1",
        f"WIDTH {width}",
        f"HEIGHT {height}",
        "VIEWPOINT 0 0 0 1 0 0 0",
        f"POINTS {width * height}",
        f"DATA {'binary' if binary else 'ascii'}",
    ]
    body = records.tobytes() if binary else _ascii_rows(records.reshape(-1))
    path = Path(path)
    path.write_bytes(("\n".join(lines) + "\n").encode("ascii") + body)
    return path


def _pcd_header(raw: bytes, path: Path) -> tuple[dict[str, list[str]], int]:
    """Header entries by keyword and the offset of the data."""
    header: dict[str, list[str]] = {}
    offset = 0
    while offset < len(raw):
        end = raw.find(b"\n", offset)
        end = len(raw) if end < 0 else end
        line = raw[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            return header, offset
    raise ValueError(f"{path}: not a PCD file (no DATA line in the header)")


def _pcd_dtype(header: dict[str, list[str]], path: Path) -> np.dtype:
    fields = header.get("FIELDS", [])
    sizes, types = header.get("SIZE", []), header.get("TYPE", [])
    counts = header.get("COUNT", ["1"] * len(fields))
    if not fields or not len(fields) == len(sizes) == len(types) == len(counts):
        raise ValueError(f"{path}: PCD header needs FIELDS, SIZE, TYPE (and COUNT) of equal length")
    parts = []
    for name, size, kind, count in zip(fields, sizes, types, counts):
        code = _PCD_TYPES.get((kind.upper(), int(size)))
        if code is None:
            raise ValueError(f"{path}: PCD field {name!r} has unsupported TYPE {kind} SIZE {size}")
        parts.append((name, code, (int(count),)) if int(count) > 1 else (name, code))
    return np.dtype(parts)


def read_pcd(path: str | Path) -> PointCloud:
    """Read a PCD v0.7 file (DATA ascii or binary; fields x, y, z required, intensity optional).

    The cloud comes back as (HEIGHT, WIDTH, 3) float64. ValueError on a file
    that is not PCD, lacks x/y/z, or uses ``binary_compressed``.
    """
    path = Path(path)
    raw = path.read_bytes()
    header, offset = _pcd_header(raw, path)
    dtype = _pcd_dtype(header, path)
    try:
        width, height = int(header["WIDTH"][0]), int(header.get("HEIGHT", ["1"])[0])
        points = int(header.get("POINTS", [str(width * height)])[0])
    except (KeyError, IndexError, ValueError):
        raise ValueError(f"{path}: PCD header needs numeric WIDTH, HEIGHT and POINTS") from None
    if points != width * height:
        raise ValueError(f"{path}: POINTS {points} is not WIDTH x HEIGHT = {width * height}")
    mode = header["DATA"][0].lower() if header["DATA"] else ""
    if mode == "binary":
        if len(raw) - offset < points * dtype.itemsize:
            raise ValueError(f"{path}: binary data hold fewer than the {points} points of the header")
        data = np.frombuffer(raw, dtype=dtype, count=points, offset=offset)
    elif mode == "ascii":
        columns = sum(int(np.prod(dtype[name].shape or (1,))) for name in dtype.names)
        table = np.loadtxt(raw[offset:].decode("ascii").splitlines(), dtype=np.float64, ndmin=2)
        if table.shape != (points, columns):
            raise ValueError(f"{path}: ascii data are {table.shape[0]} x {table.shape[1]}, expected {points} x {columns}")
        data = np.empty(points, dtype=dtype)
        column = 0
        for name in dtype.names:
            n = int(np.prod(dtype[name].shape or (1,)))
            data[name] = table[:, column] if n == 1 else table[:, column:column + n]
            column += n
    elif mode == "binary_compressed":
        raise ValueError(f"{path}: DATA binary_compressed is not supported; save it as binary or ascii")
    else:
        raise ValueError(f"{path}: unknown PCD DATA mode {mode!r}")
    if not {"x", "y", "z"} <= set(dtype.names):
        raise ValueError(f"{path}: PCD file has no x, y, z fields (FIELDS {' '.join(dtype.names)})")
    xyz = np.stack([data[c].astype(np.float64) for c in "xyz"], axis=-1).reshape(height, width, 3)
    intensity = data["intensity"].astype(np.float64).reshape(height, width) if "intensity" in dtype.names else None
    return PointCloud(xyz, intensity)


# ---------------------------------------------------------------------- PLY
def write_ply(path: str | Path, xyz: np.ndarray, intensity: np.ndarray | None = None, *, binary: bool = True,
              comment: str = "") -> Path:
    """Write the valid points of an organized cloud ((H, W, 3) mm, NaN = invalid) as PLY 1.0.

    Binary little endian (or ascii), one ``vertex`` element with float x, y,
    z, intensity, in row-major order; the organized width and height go in a
    comment, as PLY has no organization. ``comment``: one more comment line.
    """
    records = _records(xyz, intensity)
    height, width = records.shape
    flat = records.reshape(-1)
    flat = flat[np.isfinite(flat["x"]) & np.isfinite(flat["y"]) & np.isfinite(flat["z"])]
    lines = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
             f"comment labctl organized width {width} height {height}, invalid points left out"]
    if comment:
        lines.append("comment " + " ".join(comment.split()))
    lines += [f"element vertex {flat.size}", "property float x", "property float y", "property float z",
              "property float intensity", "end_header"]
    body = flat.tobytes() if binary else _ascii_rows(flat)
    path = Path(path)
    path.write_bytes(("\n".join(lines) + "\n").encode("ascii") + body)
    return path


def _ply_header(raw: bytes, path: Path) -> tuple[str, list[str], list[tuple[str, int, list[list[str]]]], int]:
    """(format, comments, elements as (name, count, property lines), data offset)."""
    if not raw.startswith(b"ply"):
        raise ValueError(f"{path}: not a PLY file (it does not start with 'ply')")
    end = raw.find(b"end_header")
    if end < 0:
        raise ValueError(f"{path}: PLY header has no end_header")
    offset = raw.find(b"\n", end) + 1
    fmt, comments, elements = "", [], []
    for line in raw[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] in ("comment", "obj_info"):
            comments.append(line.partition(" ")[2].strip())
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            elements[-1][2].append(words[1:])
    if fmt not in _PLY_ORDER:
        raise ValueError(f"{path}: unknown PLY format {fmt!r}")
    return fmt, comments, elements, offset


def read_ply(path: str | Path) -> PointCloud:
    """Read the vertices of a PLY 1.0 file (ascii or binary; the vertex element first, with x, y, z).

    Returns an unorganized cloud (1, N, 3) with ``intensity`` (or CloudCompare's
    ``scalar_intensity``) when present, and the header comments.
    """
    path = Path(path)
    raw = path.read_bytes()
    fmt, comments, elements, offset = _ply_header(raw, path)
    if not elements or elements[0][0] != "vertex":
        raise ValueError(f"{path}: PLY file does not start with a vertex element")
    _, count, properties = elements[0]
    if any(p[0] == "list" for p in properties):
        raise ValueError(f"{path}: PLY vertex element has list properties")
    try:
        dtype = np.dtype([(p[1], _PLY_ORDER[fmt] + _PLY_TYPES[p[0]]) for p in properties])
    except (KeyError, IndexError):
        raise ValueError(f"{path}: PLY vertex element has an unknown property type") from None
    if fmt == "ascii":
        lines = raw[offset:].decode("ascii").splitlines()[:count]
        table = np.loadtxt(lines, dtype=np.float64, ndmin=2) if count else np.zeros((0, len(properties)))
        if table.shape != (count, len(properties)):
            raise ValueError(f"{path}: PLY ascii vertices are {table.shape}, expected ({count}, {len(properties)})")
        data = np.empty(count, dtype=dtype)
        for k, name in enumerate(dtype.names):
            data[name] = table[:, k]
    else:
        if len(raw) - offset < count * dtype.itemsize:
            raise ValueError(f"{path}: PLY binary data hold fewer than the {count} vertices of the header")
        data = np.frombuffer(raw, dtype=dtype, count=count, offset=offset)
    names = {name.lower(): name for name in dtype.names}
    if not {"x", "y", "z"} <= set(names):
        raise ValueError(f"{path}: PLY vertices have no x, y, z")
    xyz = np.stack([data[names[c]].astype(np.float64) for c in "xyz"], axis=-1).reshape(1, count, 3)
    key = names.get("intensity", names.get("scalar_intensity"))
    intensity = data[key].astype(np.float64).reshape(1, count) if key else None
    return PointCloud(xyz, intensity, tuple(comments))
