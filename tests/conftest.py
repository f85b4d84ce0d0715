"""Shared fixtures: small simulated sensors and campaign files written on the fly."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from drivers.libusb import ensure_libusb

# test modules import pyrealsense2 directly: resolve its libusb first (the system's or libusb-package's)
ensure_libusb()

# null replicas are simulated in every test that asks for them, never taken from labctl's cache
# (labctl/reconcile/replica_cache.py; the cache's own test sets a directory); subprocesses inherit this
os.environ["LABCTL_CACHE_DIR"] = ""

if os.environ.get("PYTEST_XDIST_WORKER"):
    # one pytest-xdist worker per core: the compiled kernels run single-threaded in each, instead of
    # every worker starting a thread per core (oversubscribed, the suite ran twice as long)
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")

#: address space a test process may take. The whole suite stays under 1.3 GB resident per process; a test that
#: runs away (a sweep of 10^10 planned positions once did) gets a MemoryError and fails alone, instead of being
#: killed by the kernel's OOM killer, which took its pytest-xdist worker down and left the run waiting forever
TEST_ADDRESS_SPACE_BYTES = 10 * 1000**3
_soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
if _soft == resource.RLIM_INFINITY or _soft > TEST_ADDRESS_SPACE_BYTES:
    resource.setrlimit(resource.RLIMIT_AS, (TEST_ADDRESS_SPACE_BYTES, _hard))

#: the xdist group of the tests that need the CPU on time and of those that take every core
REALTIME_GROUP = "realtime"


def pytest_itemcollected(item: pytest.Item) -> None:
    """A test marked ``realtime`` runs in the xdist group of the same name (``--dist loadgroup``: on one
    worker, one after another), where the batch tests' Dask clusters run too: never two of them at once.
    (Marked as it is collected: pytest-xdist names the groups when the collection is modified.)"""
    if item.get_closest_marker("realtime") is not None and item.get_closest_marker("xdist_group") is None:
        item.add_marker(pytest.mark.xdist_group(REALTIME_GROUP))


SMALL_MODEL = """\
camera = "{camera}"
[camera_overrides]
width = {width}
height = {height}
"""


#: a slanted edge near the camera, then a checkerboard and a Boehler star at its best focus (the lens of
#: ``focused_model`` is sharp on the edge's grid)
BEST_FOCUS_PROCEDURES = """
[[procedure]]
kind = "slanted_edge"
start_mm = 300
stop_mm = 900
step_mm = 100
frames = 4
exposure_table = [[100, 60], [200, 250], [400, 1000]]

[[procedure]]
kind = "checkerboard"
distance_mm = "best_focus"
frames = 4

[[procedure]]
kind = "boehler_star"
distance_mm = "best_focus"
segments = [72]
gap_mm = 250
frames = 4
"""


def campaign_text(
    *,
    backend: str = "blaze",
    procedures: str | None = None,
    faults: str = "",
    seed: int = 7,
    extra_devices: str = "",
    camera: str = "",
) -> str:
    """A small wall campaign: offset calibration + short depth sweep (``camera``: more lines of
    ``[devices.camera]``)."""
    if procedures is None:
        procedures = """
        [[procedure]]
        kind = "offset_calibration"
        frames = 8

        [[procedure]]
        kind = "depth_sweep"
        start_mm = 1000
        stop_mm = 3000
        step_mm = 500
        frames = 8
        """
    text = f"""
    [campaign]
    name = "test"

    [devices.camera]
    backend = "{backend}"
    {camera}

    [devices.stage]
    protocol = "zaber"
    travel_mm = [0, 4000]

    [devices.laser]
    port = "/dev/null"
    {extra_devices}
    {procedures}

    [sim]
    seed = {seed}
    {faults}
    """
    return textwrap.dedent(text)


@pytest.fixture
def write_campaign(tmp_path: Path):
    def write(name: str = "campaign.toml", **kwargs) -> Path:
        path = tmp_path / name
        path.write_text(campaign_text(**kwargs))
        return path

    return write


@pytest.fixture
def small_model(tmp_path: Path):
    def write(camera: str = "blaze101", width: int = 48, height: int = 36) -> Path:
        path = tmp_path / f"model_{camera}_{width}x{height}.toml"
        path.write_text(SMALL_MODEL.format(camera=camera, width=width, height=height))
        return path

    return write


@pytest.fixture
def focused_model(small_model):
    """A blaze-101 model at 192 x 144 whose lens is sharp from 400 mm on: a slanted edge finds its best focus."""
    def write() -> Path:
        path = small_model(width=192, height=144)
        path.write_text(path.read_text().replace("[camera_overrides]", "[effects.defocus]\nhyperfocal_mm = 400\n"
                                                                          "[camera_overrides]"))
        return path

    return write


def run_labctl(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """Run the real command line in a subprocess."""
    return subprocess.run(
        [sys.executable, "-m", "labctl", *map(str, args)],
        capture_output=True, text=True, timeout=timeout,
    )


@pytest.fixture
def labctl():
    return run_labctl


@pytest.fixture(scope="session")
def evaluated_small_campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The output directory of ``labctl evaluate --no-pdf`` on a simulated run of :func:`campaign_text` (with a
    depth origin offset), made once per test session for the tests that read its outputs."""
    from labctl.cli import main

    tmp = tmp_path_factory.mktemp("evaluated")
    campaign = tmp / "c.toml"
    campaign.write_text(campaign_text(camera="depth_origin_offset_mm = 42.0"))
    for command in (["run", str(campaign), "--sim", "-o", str(tmp / "r.h5"), "--quiet"],
                    ["evaluate", str(tmp / "r.h5"), "-o", str(tmp / "out"), "--quiet", "--no-pdf"]):
        with pytest.raises(SystemExit) as info:
            main(command)
        assert info.value.code == 0
    return tmp / "out"
