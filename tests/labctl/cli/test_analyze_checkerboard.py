"""`labctl analyze checkerboard` (README.md, Command line): JSON keys and values, text output, figure, input errors."""

import json

import cv2
import numpy as np
import pytest

from labctl.cli import main
from labctl.report.pointcloud_io import write_pcd
from metrics.distortion import cloud_distortion, detect_corners, distortion
from sim.model import default_model_text, parse_model
from sim.preview import simulate_frame

ARGS = ("--tile-mm", "19", "--distance-mm", "599.8", "--fov-deg", "56,44")


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


@pytest.fixture(scope="module")
def board(tmp_path_factory):
    """A simulated flexx2 board with barrel distortion in image and cloud, as .npy and 16-bit .png."""
    model = parse_model(default_model_text("flexx2") + "[effects.radial_distortion]\nk1 = -0.06\n")
    x, y, z, intensity, _ = simulate_frame(model, "checkerboard", {"tile_mm": 19.0}, distance_mm=600.0)
    folder = tmp_path_factory.mktemp("board")
    np.save(folder / "image.npy", intensity)
    np.save(folder / "cloud.npy", np.dstack([x, y, z]))
    cv2.imwrite(str(folder / "image.png"), np.clip(intensity / intensity.max() * 65535, 0, 65535).astype(np.uint16))
    return folder, intensity, np.dstack([x, y, z])


def test_json_has_the_contract_keys_and_the_metric_values(board, capsys, tmp_path):
    folder, intensity, cloud = board
    figure = tmp_path / "both.png"
    assert invoke("analyze", "checkerboard", folder / "image.npy", *ARGS, "--cloud", folder / "cloud.npy",
                  "--plot", figure, "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    corners = detect_corners(intensity)
    expected = distortion(corners, 19.0, 599.8, (56.0, 44.0))
    in_cloud = cloud_distortion(cloud, corners, 19.0, (56.0, 44.0))
    assert doc["radial_distortion_w_pct"] == pytest.approx(expected.radial_distortion_w_pct)
    assert doc["radial_distortion_h_pct"] == pytest.approx(expected.radial_distortion_h_pct)
    assert doc["fov_estimate_deg"] == pytest.approx(list(expected.fov_estimate_deg))
    assert doc["cloud_distortion_w_pct"] == pytest.approx(in_cloud.distortion_w_pct)
    assert doc["cloud_distortion_h_pct"] == pytest.approx(in_cloud.distortion_h_pct)
    assert doc["fov_estimate_deg"] == pytest.approx([56.0, 44.0], abs=0.5)
    assert doc["radial_distortion_w_pct"] < -2.5 and doc["k1"] == pytest.approx(-0.06, abs=0.005)
    assert doc["pixel_aspect_distortion_pct"] == pytest.approx(2.3, abs=0.05)  # Thesis 2024, Table 6-5, flexx2
    assert doc["n_corners"] == len(corners.uv) and doc["warnings"] == []
    assert cv2.imread(str(figure)).shape[1] > 1200  # image and cloud side by side
    write_pcd(folder / "cloud.pcd", cloud)  # the same cloud as PCD (float32)
    assert invoke("analyze", "checkerboard", folder / "image.npy", *ARGS, "--cloud", folder / "cloud.pcd",
                  "--json") == 0
    from_pcd = json.loads(capsys.readouterr().out)
    assert from_pcd["cloud_distortion_w_pct"] == pytest.approx(doc["cloud_distortion_w_pct"], abs=1e-4)
    assert from_pcd["cloud_distortion_h_pct"] == pytest.approx(doc["cloud_distortion_h_pct"], abs=1e-4)


def test_png_text_output_and_figure(board, capsys, tmp_path):
    folder, *_ = board
    figure = tmp_path / "distortion.png"
    assert invoke("analyze", "checkerboard", folder / "image.png", *ARGS, "--plot", figure) == 0
    out = capsys.readouterr().out
    assert "radial" in out and "FOV estimate 56.0" in out and "point cloud" not in out
    assert cv2.imread(str(figure)) is not None


@pytest.mark.parametrize("change,message", [
    ({"--fov-deg": "56"}, "--fov-deg"),
    ({"--fov-deg": "56,200"}, "--fov-deg"),
    ({"--fov-deg": "56,x"}, "--fov-deg"),
    ({"--distance-mm": "-600"}, "positive"),
])
def test_bad_arguments_exit_2(board, capsys, change, message):
    folder, *_ = board
    args = dict(zip(ARGS[::2], ARGS[1::2])) | change
    assert invoke("analyze", "checkerboard", folder / "image.npy", *[v for kv in args.items() for v in kv]) == 2
    assert message in capsys.readouterr().err


def test_bad_files_exit_2(board, capsys, tmp_path):
    folder, intensity, cloud = board
    assert invoke("analyze", "checkerboard", tmp_path / "missing.png", *ARGS) == 2
    assert "missing.png" in capsys.readouterr().err
    np.save(tmp_path / "blank.npy", np.full((172, 224), 100.0))
    assert invoke("analyze", "checkerboard", tmp_path / "blank.npy", *ARGS) == 2
    assert "no checkerboard" in capsys.readouterr().err
    np.save(tmp_path / "small.npy", cloud[:-1])
    assert invoke("analyze", "checkerboard", folder / "image.npy", *ARGS, "--cloud", tmp_path / "small.npy") == 2
    assert "do not match the image" in capsys.readouterr().err
    (tmp_path / "cloud.txt").write_text("1 2 3\n")
    assert invoke("analyze", "checkerboard", folder / "image.npy", *ARGS, "--cloud", tmp_path / "cloud.txt") == 2
    assert "unsupported" in capsys.readouterr().err
    assert invoke("analyze", "checkerboard", folder / "image.npy", "--distance-mm", "600", "--fov-deg", "56,44") == 2
