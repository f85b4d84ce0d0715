"""Run file layout (docs/runfile.md) and its crash-safety rules."""

import json
import math
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

from drivers.protocols import CameraInfo, DeviceIdentity, Frame
from labctl.errors import InputError
from labctl.run.store import CHANNELS, FrameError, RunReader, RunWriter
from procedures.steps import Step
from tests.conftest import campaign_text

BLOSC_FILTER_ID = 32001
CAMERA = CameraInfo(width=8, height=6, fov_deg=(67.0, 51.0), pixel_pitch_um=10.0, frame_rate_hz=30.0,
                    wavelength_nm=940.0, confidence_dtype="uint16")


def make_run(path, sim=None, **kwargs):
    return RunWriter.create(
        path, campaign_toml="[campaign]\nname='x'\n", simulated=sim is not None,
        devices={"camera": (DeviceIdentity("sim", "cam", "S1", "1.0"), {"exposure_us": 100})},
        camera=CAMERA, sim=sim, **{"steps": 4, **kwargs},
    )


def frame(value: float, t: float = 0.0) -> Frame:
    a = np.full((6, 8), value, np.float32)
    return Frame(a, a, a, a, np.full((6, 8), 7, np.uint16), t)


def test_layout_matches_contract(tmp_path):
    path = tmp_path / "r.h5"
    run = make_run(path, sim=('camera = "blaze101"\n', 3))
    step = Step(index=4, procedure="depth_sweep", target="wall", frames=3, distance_mm=1000.0)
    writer = run.begin_step(step, stage_position_mm=1000.0)
    for k in range(3):
        writer.write(k, frame(1000.0 + k, t=k / 30))
    writer.commit({"reference_distance_mm": 1001.0, "laser_distance_mm": 1040.0, "exposure_us": 100.0,
                   "settings_json": "{}"})
    run.set_status("complete")
    run.close()
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == "labctl-run" and f.attrs["format_version"] == 1
        assert f.attrs["compression"] == "blosc-lz4"
        for key in ("labctl_version", "created", "campaign_toml", "status", "simulated", "compression"):
            assert key in f.attrs
        assert f.attrs["status"] == "complete" and bool(f.attrs["simulated"])
        assert f["devices/camera"].attrs["serial"] == "S1"
        assert json.loads(f["devices/camera"].attrs["settings_json"]) == {"exposure_us": 100}
        cam = f["camera"].attrs
        assert (cam["width"], cam["height"]) == (8, 6) and list(cam["fov_deg"]) == [67.0, 51.0]
        g = f["steps/00004_depth_sweep"]
        for key in ("procedure", "index", "target", "stage_position_mm", "robot_angle_deg", "laser_distance_mm",
                    "reference_distance_mm", "exposure_us", "settings_json", "started", "finished", "complete"):
            assert key in g.attrs, key
        assert math.isnan(g.attrs["robot_angle_deg"])
        for name in ("x", "y", "z", "intensity"):
            assert g[name].shape == (3, 6, 8) and g[name].dtype == np.float32
            assert g[name].chunks == (1, 6, 8)
            # the Blosc filter: HDF5 registered filter 32001 (The HDF Group, "Registered Filter Plugins")
            assert g[name].id.get_create_plist().get_filter(0)[0] == BLOSC_FILTER_ID
        assert g["confidence"].dtype == np.uint16
        assert g["timestamp"].dtype == np.float64 and g["timestamp"].shape == (3,)
        np.testing.assert_array_equal(g["z"][:, 0, 0], [1000, 1001, 1002])
        assert f["sim"].attrs["seed"] == 3


@pytest.mark.parametrize("compression", ["blosc-lz4", "none"])
def test_frames_read_back_bit_exact(tmp_path, compression):
    """Lossless: every bit of noisy float depth, NaN holes and uint16 confidence comes back."""
    rng = np.random.default_rng(1)
    path = tmp_path / "r.h5"
    run = make_run(path, compression=compression)
    writer = run.begin_step(Step(index=0, procedure="depth_sweep", target="wall", frames=4, distance_mm=1000.0), 1000.0)
    written = []
    for k in range(4):
        z = (1000 + rng.standard_normal((6, 8))).astype(np.float32)
        z[rng.random((6, 8)) < 0.2] = np.nan
        f = Frame(z * 0.1, z * 0.2, z, rng.random((6, 8), np.float32), rng.integers(0, 65535, (6, 8), np.uint16), k)
        writer.write(k, f)
        written.append(f)
    writer.commit({})
    run.close()
    with RunReader(path) as reader:
        rec = reader.step("00000_depth_sweep")
        assert reader.attrs["compression"] == compression
        for name in CHANNELS:
            expected = np.stack([getattr(f, name) for f in written])
            stored = rec.read(name)
            assert stored.dtype == expected.dtype
            assert stored.tobytes() == expected.tobytes(), name
        filters = rec.group["z"].id.get_create_plist().get_nfilters()
        assert filters == (0 if compression == "none" else 1)


def test_unknown_compression_is_refused_before_writing(tmp_path):
    with pytest.raises(ValueError, match="unknown compression 'zip'"):
        make_run(tmp_path / "r.h5", compression="zip")
    assert list(tmp_path.iterdir()) == []


def test_nothing_outside_sim_mentions_the_model(tmp_path):
    path = tmp_path / "r.h5"
    make_run(path, sim=('camera = "blaze101"\n[camera_overrides]\nnoise_mm_at_2m = 1.2345\n', 3)).close()
    found = []
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if not name.startswith("sim"):
                for value in obj.attrs.values():
                    if "1.2345" in str(value):
                        found.append(name)
        f.visititems(visit)
        for value in f.attrs.values():
            assert "1.2345" not in str(value)
    assert not found


def test_existing_file_is_not_overwritten(tmp_path):
    path = tmp_path / "r.h5"
    path.write_text("keep")
    with pytest.raises(InputError, match="already exists"):
        make_run(path)
    assert path.read_text() == "keep"


def test_incomplete_steps_are_invisible_and_discarded(tmp_path):
    path = tmp_path / "r.h5"
    run = make_run(path)
    done = run.begin_step(Step(0, "depth_sweep", "wall", 1), None)
    done.write(0, frame(1.0))
    done.commit({})
    partial = run.begin_step(Step(1, "depth_sweep", "wall", 2), None)
    partial.write(0, frame(2.0))
    assert set(run.completed()) == {"00000_depth_sweep"}
    assert run.discard_incomplete() == ["00001_depth_sweep"]
    run.close()
    with RunReader(path) as reader:
        assert [s.step_id for s in reader.steps()] == ["00000_depth_sweep"]


def test_bad_frames_are_refused_with_a_reason(tmp_path):
    run = make_run(tmp_path / "r.h5")
    writer = run.begin_step(Step(0, "depth_sweep", "wall", 2), None)
    bad = frame(1.0)
    bad.z = np.zeros((5, 8), np.float32)
    with pytest.raises(FrameError, match=r"z has shape \(5, 8\), expected \(6, 8\)"):
        writer.write(0, bad)
    with pytest.raises(FrameError, match="outside 0..1"):
        writer.write(2, frame(1.0))


def test_reader_refuses_foreign_and_future_files(tmp_path):
    foreign = tmp_path / "f.h5"
    with h5py.File(foreign, "w") as f:
        f.attrs["format"] = "other"
    with pytest.raises(InputError, match="not a labctl run file"):
        RunReader(foreign)
    future = tmp_path / "g.h5"
    make_run(future).close()
    with h5py.File(future, "r+") as f:
        f.attrs["format_version"] = 99
    with pytest.raises(InputError, match="format version 99"):
        RunReader(future)


def test_channels_constant_matches_contract():
    assert CHANNELS == ("x", "y", "z", "intensity", "confidence")


def test_a_run_works_with_hdf5_plugin_path_at_hdf5plugins_own_filters(tmp_path):
    """hdf5plugin's documentation advises HDF5_PLUGIN_PATH=hdf5plugin.PLUGIN_PATH for other HDF5 tools (HDFView);
    with it set, HDF5 loads the Blosc plugin by itself, which failed every compressed dataset at the first step.
    A simulated run in a fresh process with that environment completes, and its frames read back."""
    import hdf5plugin

    campaign = tmp_path / "c.toml"
    campaign.write_text(campaign_text())
    run = tmp_path / "r.h5"
    env = {**os.environ, "HDF5_PLUGIN_PATH": hdf5plugin.PLUGIN_PATH}
    done = subprocess.run([sys.executable, "-m", "labctl", "run", str(campaign), "--sim", "-o", str(run), "--quiet"],
                          capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    with RunReader(run) as reader:
        steps = reader.steps()
        assert reader.attrs["compression"] == "blosc-lz4" and steps
        assert np.isfinite(steps[-1].frame("z", 0)).any()


READ_PLAIN = """
import sys, h5py
with h5py.File(sys.argv[1], "r") as f:
    print(f.attrs["how_to_read"])
    z = f["steps"][next(iter(f["steps"]))]["z"]
    try:
        z[0]
        print("READ WITHOUT THE FILTER")
    except OSError as error:
        print("ERROR", error)
    import hdf5plugin
    print("READ", float(z[0][0, 0]))
"""


def test_the_file_says_how_to_read_it_and_the_advice_works(tmp_path):
    """A compressed run file opened by plain h5py in a fresh process: its root attribute ``how_to_read`` (an
    attribute passes through no filter) names ``import hdf5plugin``; a frame fails to read without it, and reads
    after following the advice."""
    path = tmp_path / "r.h5"
    run = make_run(path)
    writer = run.begin_step(Step(index=0, procedure="depth_sweep", target="wall", frames=1, distance_mm=1000.0), 1000.0)
    writer.write(0, frame(1234.0))
    writer.commit({"reference_distance_mm": 1000.0})
    run.close()
    env = {k: v for k, v in os.environ.items() if k != "HDF5_PLUGIN_PATH"}
    env["HDF5_PLUGIN_PATH"] = str(tmp_path / "no-plugins")  # no system plugin folder either
    done = subprocess.run([sys.executable, "-c", READ_PLAIN, str(path)], capture_output=True, text=True, env=env,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    advice, attempt, after = done.stdout.strip().split("\n")
    assert "import hdf5plugin" in advice and "HDF5_PLUGIN_PATH" in advice
    assert attempt.startswith("ERROR")
    assert after == "READ 1234.0"
