"""Recording budget: sustained stack writes >= 2x the AM-T100's data rate (DESIGN "Budgets").

The AM-T100 delivers 640 x 480 at 60 fps: x, y, z, intensity (float32) and
confidence (uint16), 5.5 MB per frame, 332 MB/s. The benchmark writes 300
frames through the run store (one step, commit with fsync) and compares the
frame rate with twice the camera's. The floor is the same bytes written with
plain ``os.write`` and one fsync, measured in the same run: it shows how close
the store comes to what the disk allows.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bench.common import Result, best_of, scratch_dir
from drivers.protocols import CameraInfo, DeviceIdentity, Frame
from labctl.store import RunWriter
from procedures.steps import Step

WIDTH, HEIGHT, FPS = 640, 480, 60.0
FRAMES = 300


def _frames() -> list[Frame]:
    rng = np.random.default_rng(0)
    frames = []
    for k in range(8):
        z = (2000 + rng.standard_normal((HEIGHT, WIDTH), dtype=np.float32)).astype(np.float32)
        frames.append(Frame(z * 0.3, z * 0.2, z, z * 10, (z * 30).astype(np.uint16), k / FPS))
    return frames


def _frame_bytes() -> int:
    return WIDTH * HEIGHT * (4 * 4 + 2)


def _store(directory: Path, frames: list[Frame], tag: int) -> None:
    camera = CameraInfo(WIDTH, HEIGHT, (67.0, 51.0), 10.0, FPS, 850.0, "uint16")
    run = RunWriter.create(
        directory / f"run{tag}.h5", campaign_toml="", simulated=True,
        devices={"camera": (DeviceIdentity("bench", "bench", "0", "0"), {})}, camera=camera,
    )
    writer = run.begin_step(Step(0, "depth_sweep", "wall", FRAMES), None)
    for k in range(FRAMES):
        writer.write(k, frames[k % len(frames)])
    writer.commit({})
    run.close()
    os.remove(directory / f"run{tag}.h5")


def _raw(directory: Path, frames: list[Frame], tag: int) -> None:
    path = directory / f"raw{tag}.bin"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    try:
        for k in range(FRAMES):
            f = frames[k % len(frames)]
            for array in (f.x, f.y, f.z, f.intensity, f.confidence):
                os.write(fd, memoryview(np.ascontiguousarray(array)).cast("B"))
        os.fsync(fd)
    finally:
        os.close(fd)
    os.remove(path)


def run() -> Result:
    frames = _frames()
    with scratch_dir() as tmp:
        directory = Path(tmp)
        counter = iter(range(1000))
        store_s = best_of(3, lambda: _store(directory, frames, next(counter)))
        raw_s = best_of(3, lambda: _raw(directory, frames, next(counter)))
    fps = FRAMES / store_s
    required = 2 * FPS
    mb_s = fps * _frame_bytes() / 1e6
    return Result(
        name="recording (640x480 x/y/z/intensity/confidence)",
        measured=f"{fps:.0f} frames/s = {mb_s:.0f} MB/s, {fps / FPS:.1f}x the AM-T100's 60 fps",
        floor=f"raw os.write {FRAMES / raw_s:.0f} frames/s",
        ratio=fps / required,
        budget=">= 1.0 x (2 x 60 fps)",
        ok=fps >= required,
    )
