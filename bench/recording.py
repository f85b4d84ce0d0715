"""Recording budget: sustained stack writes >= 2x the AM-T100's frame rate, with the default compression.

The AM-T100 delivers 640 x 480 at 60 fps: x, y, z, intensity (float32) and
confidence (uint16), 5.5 MB per frame, 332 MB/s. The frames are the simulated
blaze-101 (640 x 480, same layout) on the wall at three distances and on the
checkerboard, as in the demo campaign. The benchmark writes 300 frames through
the run store (one step, commit with fsync) with the default compression and
with none, and compares the compressed frame rate with twice the camera's. It
reports the compression ratio (raw bytes / file size). The floor is the same
raw bytes written with plain ``os.write`` and one fsync, measured in the same
run: it shows how close the store comes to what the disk allows, and is a
budget of its own: compression runs beside the writes, so the compressed store
keeps up with writing the raw bytes (a second result line, ratio >= 1.0). The
ways are timed in turn, three rounds in a rotating order, the best of each: a change
in the machine's load meets all alike. A fourth way is the compressed store with
the live console open (labctl.console): every frame handed to it as the runner
does, a client in a process of its own (as a browser is) polling its state and
images four times a second; its frame rate
is compared with the compressed store's without (a third result line, ratio >= 0.95).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from bench.common import Result, scratch_dir
from bench.sim_capture import CAMPAIGN
from drivers.protocols import CameraInfo, DeviceIdentity, Frame
from labctl.run.compression import DEFAULT
from labctl.run.config import parse_campaign
from labctl.run.lab import build_sim_lab
from labctl.run.observer import RunObserver
from labctl.run.planning import PlannedStep
from labctl.run.store import RunWriter
from procedures.steps import Step
from sim.model import default_model_text, parse_model

FPS = 60.0
FRAMES = 300
SCENES = (("wall", 800.0), ("wall", 1500.0), ("wall", 3000.0), ("checkerboard", 800.0))


def _frames(per_scene: int = 2) -> tuple[list[Frame], CameraInfo]:
    """Simulated blaze-101 frames of the demo's scenes."""
    lab = build_sim_lab(parse_campaign(CAMPAIGN.format(backend="blaze101")), parse_model(default_model_text("blaze101")), 1)
    lab.camera.connect()
    lab.stage.connect()
    frames = []
    for index, (target, distance) in enumerate(SCENES):
        lab.stage.move_to(distance)
        lab.camera.world.begin_step(Step(index, "depth_sweep", target, per_scene), 0.0)
        lab.camera.configure(None, {})
        frames.extend(lab.camera.capture(per_scene))
    return frames, lab.camera.info()


def _frame_bytes(f: Frame) -> int:
    return sum(a.nbytes for a in (f.x, f.y, f.z, f.intensity, f.confidence))


def _store(directory: Path, frames: list[Frame], camera: CameraInfo, compression: str, tag: int,
           observer: RunObserver | None = None) -> int:
    """Write the stack, each frame handed to ``observer`` too; the file's size in bytes."""
    path = directory / f"run{tag}.h5"
    run = RunWriter.create(
        path, campaign_toml="", simulated=True,
        devices={"camera": (DeviceIdentity("bench", "bench", "0", "0"), {})}, camera=camera, steps=1,
        compression=compression,
    )
    writer = run.begin_step(Step(0, "depth_sweep", "wall", FRAMES), None)
    for k in range(FRAMES):
        writer.write(k, frames[k % len(frames)])
        if observer is not None:
            observer.frame(writer.step.step_id, k, frames[k % len(frames)], 0.0)
    writer.commit({})
    run.close()
    size = path.stat().st_size
    os.remove(path)
    return size


def _raw(directory: Path, frames: list[Frame], tag: int) -> None:
    path = directory / f"raw{tag}.bin"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    try:
        for k in range(FRAMES):
            f = frames[k % len(frames)]
            for array in (f.x, f.y, f.z, f.intensity, f.confidence):
                os.write(fd, memoryview(array).cast("B"))
        os.fsync(fd)
    finally:
        os.close(fd)
    os.remove(path)


#: the watching browser: a process of its own polling the console's state and both images four times a second
_CLIENT = """
import sys, time, urllib.request
while True:
    for path in ("state.json", "depth.png", "intensity.png"):
        try:
            urllib.request.urlopen(sys.argv[1] + path, timeout=5).read()
        except OSError:
            pass  # no image yet (404)
    time.sleep(0.25)
"""


@contextmanager
def _watched_console() -> Iterator[RunObserver]:
    """A console on 127.0.0.1 with one client, in a process of its own as a browser is, polling its state and
    both images four times a second."""
    from labctl.console.session import open_console

    with open_console(announce=lambda _: None) as console:
        console.state.started([], [], lambda _: None)
        console.state.step(PlannedStep(Step(0, "depth_sweep", "wall", FRAMES), None, 0.0, 1.0), 0.0)
        client = subprocess.Popen([sys.executable, "-c", _CLIENT, console.server.url])
        try:
            yield console.state
        finally:
            client.terminate()
            client.wait()


def run() -> list[Result]:
    frames, camera = _frames()
    sizes: list[int] = []
    with scratch_dir() as tmp, _watched_console() as console:
        directory = Path(tmp)
        counter = iter(range(1000))
        ways = {
            "compressed": lambda: sizes.append(_store(directory, frames, camera, DEFAULT, next(counter))),
            "console": lambda: _store(directory, frames, camera, DEFAULT, next(counter), console),
            "plain": lambda: _store(directory, frames, camera, "none", next(counter)),
            "raw": lambda: _raw(directory, frames, next(counter)),
        }
        seconds = {name: math.inf for name in ways}
        names = list(ways)
        for round_ in range(3):  # the order rotates: no way always follows the same one (the page cache's writeback)
            for name in names[round_:] + names[:round_]:
                action = ways[name]
                start = time.perf_counter()
                action()
                seconds[name] = min(seconds[name], time.perf_counter() - start)
    compressed_s, plain_s, raw_s = seconds["compressed"], seconds["plain"], seconds["raw"]
    fps = FRAMES / compressed_s
    raw_bytes = FRAMES * _frame_bytes(frames[0])
    required = 2 * FPS
    return [
        Result(
            name=f"recording (simulated blaze-101 640x480 x/y/z/intensity/confidence, {DEFAULT})",
            measured=f"{fps:.0f} frames/s = {fps / FPS:.1f}x the AM-T100's 60 fps, compression ratio "
                     f"{raw_bytes / min(sizes):.2f} (raw / file); uncompressed store {FRAMES / plain_s:.0f} frames/s",
            floor=f"raw os.write {FRAMES / raw_s:.0f} frames/s",
            ratio=fps / required,
            budget=">= 1.0 x (2 x 60 fps)",
            ok=fps >= required,
        ),
        Result(
            name="recording, compressed vs raw floor",
            measured=f"compressed store ({DEFAULT}) {fps:.0f} frames/s",
            floor=f"raw os.write + fsync of the same frames {FRAMES / raw_s:.0f} frames/s",
            ratio=raw_s / compressed_s,
            budget=">= 1.0",
            ok=raw_s / compressed_s >= 1.0,
        ),
        Result(
            name="recording with the live console open vs without",
            measured=f"compressed store with the console {FRAMES / seconds['console']:.0f} frames/s",
            floor=f"without {fps:.0f} frames/s",
            ratio=compressed_s / seconds["console"],
            budget=">= 0.95",
            ok=compressed_s / seconds["console"] >= 0.95,
        ),
    ]
