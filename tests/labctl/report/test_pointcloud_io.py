"""Point-cloud files (PCD v0.7, PLY 1.0), ``labctl export`` and ``labctl analyze boehler``.

Headers are checked line by line against the PCD v0.7 and PLY 1.0 specifications
and the binary bodies byte by byte. (Open3D 0.20.0 read the binary and ASCII PCD
and the PLY files back to the same points and intensities when the format was
written; it is not a project dependency — 900 MB — so that check is not repeated here.)
"""

from __future__ import annotations

import json
import struct

import h5py
import numpy as np
import pytest

from labctl.cli import main
from labctl.report.pointcloud_io import read_pcd, read_ply, write_pcd, write_ply
from labctl.run.store import RunReader
from metrics.boehler import analyze_boehler
from metrics.stack import stack_stats

STEP = "00000_boehler_star"
BOEHLER = """
[[procedure]]
kind = "boehler_star"
distance_mm = 500
segments = 24
frames = 3
"""


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


def cloud_with_holes(height: int = 4, width: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    xyz = rng.normal(0.0, 100.0, (height, width, 3)).astype(np.float32)
    xyz[..., 2] += 1000.0
    xyz[1, 2] = np.nan
    xyz[height - 1, 0] = np.nan
    intensity = rng.uniform(0.0, 4000.0, (height, width)).astype(np.float32)
    return xyz, intensity


def split_header(raw: bytes, last: bytes) -> tuple[list[str], bytes]:
    end = raw.index(last) + len(last) + 1
    return raw[:end].decode("ascii").splitlines(), raw[end:]


@pytest.mark.parametrize("binary", [True, False])
def test_pcd_round_trip_keeps_organization_and_nan(tmp_path, binary):
    xyz, intensity = cloud_with_holes()
    path = write_pcd(tmp_path / "c.pcd", xyz, intensity, binary=binary)
    cloud = read_pcd(path)
    assert cloud.organized and cloud.xyz.shape == (4, 5, 3)
    np.testing.assert_array_equal(cloud.xyz, xyz.astype(float))  # NaN where NaN, float32 exact (9 digits in ascii)
    np.testing.assert_array_equal(cloud.intensity, intensity.astype(float))


def test_pcd_header_and_binary_body_follow_the_spec(tmp_path):
    xyz, intensity = cloud_with_holes()
    raw = write_pcd(tmp_path / "c.pcd", xyz, intensity, comment="from a test").read_bytes()
    header, body = split_header(raw, b"DATA binary")
    assert header == [
        "# .PCD v0.7 - Point Cloud Data file format", "# from a test", "VERSION 0.7", "FIELDS x y z intensity",
        "SIZE 4 4 4 4", "TYPE F F F F", "COUNT 1 1 1 1", "WIDTH 5", "HEIGHT 4", "VIEWPOINT 0 0 0 1 0 0 0",
        "POINTS 20", "DATA binary",
    ]
    assert len(body) == 20 * 16
    # row-major (row 0 first), little-endian float32 records x y z intensity
    assert body[16 * 6:16 * 7] == struct.pack("<4f", *xyz[1, 1], intensity[1, 1])
    assert body[16 * 7:16 * 8] == struct.pack("<4f", np.nan, np.nan, np.nan, intensity[1, 2])


def test_pcd_ascii_body(tmp_path):
    xyz, intensity = cloud_with_holes()
    header, body = split_header(write_pcd(tmp_path / "c.pcd", xyz, intensity, binary=False).read_bytes(),
                                b"DATA ascii")
    assert header[-1] == "DATA ascii" and header[6:8] == ["WIDTH 5", "HEIGHT 4"]
    rows = body.decode("ascii").splitlines()
    assert len(rows) == 20 and rows[7] == f"nan nan nan {float(intensity[1, 2]):.9g}"
    first = np.array(rows[0].split(), dtype=float).astype(np.float32)  # 9 digits: the float32 comes back exactly
    np.testing.assert_array_equal(first, [*xyz[0, 0], intensity[0, 0]])


def test_read_pcd_refuses_what_it_cannot_read(tmp_path):
    path = write_pcd(tmp_path / "c.pcd", *cloud_with_holes())
    raw = path.read_bytes()
    (tmp_path / "compressed.pcd").write_bytes(raw.replace(b"DATA binary", b"DATA binary_compressed"))
    with pytest.raises(ValueError, match="binary_compressed"):
        read_pcd(tmp_path / "compressed.pcd")
    (tmp_path / "short.pcd").write_bytes(raw[:-16])
    with pytest.raises(ValueError, match="fewer than the 20 points"):
        read_pcd(tmp_path / "short.pcd")
    (tmp_path / "no.pcd").write_bytes(b"hello\n")
    with pytest.raises(ValueError, match="not a PCD file"):
        read_pcd(tmp_path / "no.pcd")


@pytest.mark.parametrize("binary", [True, False])
def test_ply_holds_the_valid_points_and_the_organized_size(tmp_path, binary):
    xyz, intensity = cloud_with_holes()
    path = write_ply(tmp_path / "c.ply", xyz, intensity, binary=binary, comment="from a test")
    fmt = "binary_little_endian" if binary else "ascii"
    header, body = split_header(path.read_bytes(), b"end_header")
    assert header == [
        "ply", f"format {fmt} 1.0", "comment labctl organized width 5 height 4, invalid points left out",
        "comment from a test", "element vertex 18", "property float x", "property float y", "property float z",
        "property float intensity", "end_header",
    ]
    valid = np.isfinite(xyz).all(axis=-1)
    if binary:
        assert body == np.column_stack([xyz[valid], intensity[valid]]).astype("<f4").tobytes()
    cloud = read_ply(path)
    assert not cloud.organized and cloud.organized_size == (5, 4)
    np.testing.assert_array_equal(cloud.xyz[0], xyz[valid].astype(float))
    np.testing.assert_array_equal(cloud.intensity[0], intensity[valid].astype(float))


@pytest.fixture
def star_run(tmp_path, write_campaign, small_model):
    """A simulated run with one 24-segment star step, star at 500 mm (160 x 120 px, 3 frames)."""
    run = tmp_path / "star.h5"
    model = small_model(width=160, height=120)
    assert invoke("run", write_campaign(procedures=BOEHLER), "--sim", "--model", model, "-o", run, "--quiet") == 0
    return run


def test_export_pcd_is_the_stack_mean(star_run, tmp_path):
    out = tmp_path / "star.pcd"
    assert invoke("export", star_run, "--step", STEP, "--format", "pcd", "-o", out) == 0
    cloud = read_pcd(out)
    with RunReader(star_run) as reader:
        step = reader.step(STEP)
        mean = np.stack([stack_stats(step.read(c)).mean for c in "xyz"], axis=-1)
        frame = np.stack([step.frame(c, 1) for c in "xyz"], axis=-1)
    assert cloud.xyz.shape == (120, 160, 3)
    np.testing.assert_array_equal(cloud.xyz, mean.astype(np.float32).astype(float))
    assert np.isfinite(cloud.xyz).all(axis=-1).sum() > 0.9 * 120 * 160
    assert f"{STEP} (mean of 3 frames)" in out.read_bytes()[:300].decode()

    ply = tmp_path / "frame1.ply"
    assert invoke("export", star_run, "--step", STEP, "--format", "ply", "-o", ply, "--frame", 1, "--ascii") == 0
    points = read_ply(ply)
    valid = np.isfinite(frame).all(axis=-1)
    assert points.organized_size == (160, 120)
    np.testing.assert_array_equal(points.xyz[0], frame[valid].astype(float))


def test_export_errors_name_the_problem(star_run, tmp_path, capsys):
    out = tmp_path / "x.pcd"
    assert invoke("export", star_run, "--step", "00007_nothing", "--format", "pcd", "-o", out) == 2
    assert "00007_nothing" in capsys.readouterr().err
    assert invoke("export", star_run, "--step", STEP, "--format", "pcd", "-o", out, "--frame", 3) == 2
    assert "--frame 3" in capsys.readouterr().err
    assert invoke("export", star_run, "--step", STEP, "--format", "xyz", "-o", out) == 2
    capsys.readouterr()
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f.attrs["format"] = "something-else"
    assert invoke("export", foreign, "--step", STEP, "--format", "pcd", "-o", out) == 2
    assert "not a labctl run file" in capsys.readouterr().err
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5")
    assert invoke("export", text, "--step", STEP, "--format", "pcd", "-o", out) == 2
    assert "notes.h5" in capsys.readouterr().err
    interrupted = tmp_path / "interrupted.h5"
    interrupted.write_bytes(star_run.read_bytes())
    with h5py.File(interrupted, "r+") as f:
        f["steps"][STEP].attrs["complete"] = False
    assert invoke("export", interrupted, "--step", STEP, "--format", "pcd", "-o", out) == 2
    assert "incomplete" in capsys.readouterr().err
    assert not out.exists()


# ---------------------------------------------------------------------- labctl analyze boehler
def test_analyze_boehler_on_pcd_and_npy(star_run, tmp_path, capsys):
    pcd, npy = tmp_path / "star.pcd", tmp_path / "star.npy"
    assert invoke("export", star_run, "--step", STEP, "--format", "pcd", "-o", pcd) == 0
    cloud = read_pcd(pcd).xyz
    np.save(npy, cloud)
    capsys.readouterr()
    docs = []
    for path in (pcd, npy):
        assert invoke("analyze", "boehler", path, "--segments", 24, "--binning", 6, "--fov-deg", "67,51", "--json") == 0
        docs.append(json.loads(capsys.readouterr().out))
    assert docs[0] == docs[1]
    doc = docs[0]
    expected = analyze_boehler(cloud, 24, binning=6, fov_deg=(67.0, 51.0))
    for key in ("resolution_h_mm", "resolution_v_mm", "resolution_mm", "radius_h_mm", "radius_v_mm"):
        assert doc[key] == pytest.approx(getattr(expected, key))
    # 160 x 120 pixels over 67 x 51 deg: about 4 mm per pixel at 500 mm; resolved, but not finer than that
    assert doc["resolution_h_mm"] >= doc["sensor_h_mm"] > 3.5 and doc["resolution_v_mm"] >= doc["sensor_v_mm"]
    assert doc["distance_mm"] == pytest.approx(500.0, abs=15.0)
    assert len(doc["rings"]["clusters_h"]) == len(doc["rings"]["radius_mm"])

    plot = tmp_path / "star.png"
    assert invoke("analyze", "boehler", pcd, "--segments", 24, "--binning", 2, "--plot", plot) == 0
    text = capsys.readouterr().out
    assert "24-segment star" in text and "point spacing on the star" in text  # 2 mm rings too narrow here
    assert invoke("analyze", "boehler", pcd, "--segments", 24, "--json") == 0  # --binning auto
    auto = json.loads(capsys.readouterr().out)
    assert auto["ring_width_mm"] >= 2 * auto["sensor_h_mm"] and "exceeds the ring width" not in " ".join(auto["warnings"])
    assert invoke("analyze", "boehler", pcd, "--segments", 24, "--binning", "x") == 2
    assert plot.stat().st_size > 20_000


def test_analyze_boehler_input_errors(tmp_path, capsys):
    flat = tmp_path / "flat.pcd"
    write_pcd(flat, np.zeros((1, 50, 3)))
    wrong = tmp_path / "wrong.npy"
    np.save(wrong, np.zeros((10, 10)))
    floor = tmp_path / "floor.npy"
    col, row = np.meshgrid(np.arange(80.0), np.arange(60.0))
    np.save(floor, np.dstack([col * 10 - 400, np.full_like(col, 300.0), 500 + row * 20]))
    (tmp_path / "cloud.txt").write_text("1 2 3\n")
    for path, args, message in [
        (flat, [], "not an organized"),
        (wrong, [], "not an organized"),
        (tmp_path / "cloud.txt", [], "unsupported type"),
        (tmp_path / "missing.npy", [], "not found"),
        (floor, [], "no star plane"),
        (floor, ["--fov-deg", "67"], "--fov-deg"),
    ]:
        assert invoke("analyze", "boehler", path, "--segments", 24, *args, "--json") == 2, path
        captured = capsys.readouterr()
        assert captured.out == "" and message in captured.err and "Traceback" not in captured.err
    assert invoke("analyze", "boehler", floor, "--segments", 23) == 2
    assert "--segments 23" in capsys.readouterr().err
