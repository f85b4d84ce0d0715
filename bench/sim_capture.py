"""Simulated capture budget: >= 10x each camera's real frame rate at full resolution, whole steps.

For every built-in profile (its default model) a simulated camera captures
steps of 100 frames through the device protocol, for a plain target (the
wall) and an edge-dense one (the checkerboard at 800 mm, where a third of the
pixels straddle a tile edge and are supersampled 4 x 4).

* whole step (the budget): frames per second of a 100-frame step with the
  step's one-off scene preparation (rendering, blur; once per stage position,
  robot angle or target) included: what a simulated campaign waits for;
* capture rate (reported): frames per second from the first frame of a stack
  to its last.

The ratio is the whole step's rate divided by the camera's real frame rate; the
floor printed is the time numpy needs just to allocate and fill the frame's
five output arrays, measured in the same run.
"""

from __future__ import annotations

import time

import numpy as np

from bench.common import Result
from labctl.run.config import parse_campaign
from labctl.run.lab import build_sim_lab
from procedures.steps import Step
from sim.model import default_model_text, parse_model
from sim.profiles import PROFILES

FRAMES = 100
CAMPAIGN = """
[campaign]
name = "bench"
[devices.camera]
backend = "{backend}"
[devices.stage]
protocol = "zaber"
[[procedure]]
kind = "depth_sweep"
start_mm = 800
stop_mm = 800
step_mm = 100
frames = 1
"""


def _capture_fps(profile: str, target: str, repeats: int = 2) -> tuple[float, float, float]:
    """(capture rate within a stack, rate over whole steps, seconds of preparation per step), fps."""
    lab = build_sim_lab(parse_campaign(CAMPAIGN.format(backend=profile)), parse_model(default_model_text(profile)), 1)
    lab.camera.connect()
    lab.stage.connect()
    lab.stage.move_to(800.0 if target == "checkerboard" else 2000.0)
    best, capture, prep = float("inf"), float("inf"), 0.0
    for index in range(repeats + 1):  # the first step also compiles the kernels
        lab.camera.world.begin_step(Step(index, "depth_sweep", target, FRAMES), 0.0)
        lab.camera.configure(None, {})
        start = time.perf_counter()
        frames = lab.camera.capture(FRAMES)
        next(frames)
        first = time.perf_counter()
        for _ in frames:
            pass
        total = time.perf_counter() - start
        if index and total < best:
            best, prep = total, first - start
        if index:
            capture = min(capture, (time.perf_counter() - first) / (FRAMES - 1))
    return 1.0 / capture, FRAMES / best, prep


def _fill_floor(width: int, height: int) -> float:
    start = time.perf_counter()
    for _ in range(50):
        arrays = [np.empty((height, width), np.float32) for _ in range(5)]
        for a in arrays:
            a.fill(1.0)
    return (time.perf_counter() - start) / 50


def run() -> list[Result]:
    results = []
    for name, profile in PROFILES.items():
        for target in ("wall", "checkerboard"):
            fps, step_fps, prep = _capture_fps(name, target)
            ratio = step_fps / profile.frame_rate_hz  # the whole step, its scene preparation included
            results.append(Result(
                name=f"simulated capture {name} {profile.width}x{profile.height} ({target})",
                measured=f"whole 100-frame step {step_fps:.0f} frames/s (scene preparation {prep * 1e3:.0f} ms); "
                         f"{fps:.0f} frames/s = {fps / profile.frame_rate_hz:.1f}x within the stack",
                floor=f"allocate+fill outputs {1e3 * _fill_floor(profile.width, profile.height):.2f} ms/frame",
                ratio=ratio,
                budget=f">= 10 x {profile.frame_rate_hz:g} fps",
                ok=ratio >= 10.0,
            ))
    return results
