"""Simulated runs for reconcile tests: a campaign of the library's simulator with ``/sim`` removed.

``simulated_run`` makes the plain run (the simulator with the camera's
built-in effects only, or with ``hidden`` library effects) and removes
``/sim`` so that the reconcile sees only what a measured file holds;
tests/reconcile/forward.py rewrites such a run as a camera with an effect
written from first principles would have measured it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import h5py
import pytest
import tomli_w

from labctl.cli import main
from sim.effects import default_effects
from sim.profiles import get_profile

SIZES = {"blaze101": (160, 120), "amt100": (160, 120), "flexx2": (224, 172), "d455": (160, 120)}
BACKENDS = {"blaze101": "blaze", "amt100": "amt100", "flexx2": "flexx2", "d455": "realsense"}

#: offset calibration, a 0.4-4 m depth sweep in 200 mm steps, PTFE and silicone plates at -60...60 deg on the
#: robot circle, 10 frames per stack (``{sweep_step_mm}``, ``{robot}`` and ``{seed}`` filled in)
CAMPAIGN = """
[campaign]
name = "reconcile-test"
[devices.camera]
backend = "{backend}"
[devices.stage]
protocol = "zaber"
port = "/dev/ttyUSB0"
travel_mm = [0, 4000]
speed_mm_s = 50
[devices.laser]
port = "/dev/ttyUSB1"
[devices.robot]
host = "192.168.1.10"
radius_max_mm = 850
[[procedure]]
kind = "offset_calibration"
distance_mm = 2000
frames = 10
[[procedure]]
kind = "depth_sweep"
start_mm = 400
stop_mm = 4000
step_mm = {sweep_step_mm}
frames = 10
{robot}
[sim]
seed = {seed}
"""

ROBOT = """
[[procedure]]
kind = "remission_angle"
materials = ["ptfe", "silicone"]
angles_deg = [-60, 60, 20]
radius_mm = 850
frames = 10
"""


def simulated_run(directory: Path, camera: str, hidden: dict[str, Any] | None = None, seed: int = 3,
                  campaign: str | None = None, sweep_step_mm: int = 200, robot: bool = True,
                  lab: dict[str, float] | None = None) -> Path:
    """A simulated campaign (``CAMPAIGN`` or the given campaign text) of ``camera`` at its test size with the
    built-in effects plus ``hidden`` library effects, in the default simulated lab or one with ``lab``'s values
    (sim/lab.py); ``/sim`` removed. Returns the run file's path."""
    directory.mkdir(parents=True, exist_ok=True)
    width, height = SIZES[camera]
    text = campaign if campaign is not None else CAMPAIGN.format(
        backend=BACKENDS[camera], seed=seed, sweep_step_mm=sweep_step_mm, robot=ROBOT if robot else "")
    (directory / "campaign.toml").write_text(text)
    model = {"camera": camera, "camera_overrides": {"width": width, "height": height},
             "effects": {**default_effects(get_profile(camera)), **(hidden or {})}, **({"lab": lab} if lab else {})}
    (directory / "hidden.toml").write_text(tomli_w.dumps(model))
    run = directory / "measured.h5"
    with pytest.raises(SystemExit) as info:
        main(["run", str(directory / "campaign.toml"), "--sim", "--model", str(directory / "hidden.toml"),
              "-o", str(run), "--quiet"])
    assert info.value.code == 0
    with h5py.File(run, "a") as f:
        if "sim" in f:
            del f["sim"]
    return run



def reconcile_cli(run: Path, out: Path, null_runs: int = 0) -> dict[str, Any]:
    """``labctl reconcile RUN -o OUT --null-runs K --quiet`` (must exit 0; by default the fixed thresholds, K = 0);
    returns reconcile.json."""
    with pytest.raises(SystemExit) as info:
        main(["reconcile", str(run), "-o", str(out), "--null-runs", str(null_runs), "--quiet"])
    assert info.value.code == 0
    return json.loads((out / "reconcile.json").read_text())
