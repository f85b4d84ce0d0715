"""What a measured run shows, reduced to what the reconcile workflow compares.

Every complete step that the simulator can re-create (a wall, chart, board,
star, mask or material plate) becomes a :class:`StepScene` (where the camera
was, what it saw, with which exposure and when) and an :class:`Observation`:
the stack mean of z and intensity averaged over ``bin_px`` x ``bin_px`` pixel
bins, the variance of each bin's mean estimated from the stack itself, and the
bin's valid fraction; and the statistics of the depth noise per bin:

* ``noise_mm``: the temporal noise, sqrt of the mean over the bin's pixels
  that are valid in every frame of their sample variance over the stack
  (``noise_dof`` = m (n - 1) degrees of freedom for m such pixels and n
  frames, divided by the local correlation ratio where it exceeds 1:
  correlated pixels carry less independent evidence);
* ``valid_rate``: the fraction of the bin's pixel-frames that are valid;
* ``correlation``: the variance over the stack of the frame's bin mean of
  those pixels' deviations from their own stack mean, over the per-pixel
  variance / m: 1 for independent pixels, up to m for pixels that move
  together (n - 1 degrees of freedom).

The variance of each bin's depth mean is the per-pixel variance / count / n
times the correlation ratio (pooled over the bin and its eight neighbours, so
that it rests on 9 (n - 1) degrees of freedom): spatially correlated noise
does not average out over a bin, and the comparison must not take a bin mean
for more precise than it is. At most ``max_frames`` frames per step are read
(10: the correlation ratio of one bin then has 9 degrees of freedom, a
sampling spread of 0.50 in its logarithm; labctl/reconcile/goodness.py derives
the floors from these). ``/sim`` of the file is never read.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from labctl.errors import InputError
from labctl.evaluation.read_ahead import SLOTS, read_ahead
from labctl.evaluation.uncertainty import laser_step_uncertainty
from labctl.kernel_threads import serial_kernels
from labctl.reconcile.bin_moments import binned_stack_stats
from labctl.reconcile.bin_noise import bin_noise
from labctl.reconcile.results import ExcludedStep
from labctl.run.config import parse_campaign
from labctl.run.store import RunReader, StepRecord, finite_or_none
from sim.scenes.targets import PLATE_MATERIALS, STAGE_TARGETS

#: frames of each stack read (the first ones), set by hand: enough for the bin means and the noise statistics of
#: the test campaigns (which capture 10), and a bound on reading and re-simulating a 100-frame stack; the null
#: replicas capture no more (labctl/reconcile/null.py)
MAX_FRAMES = 10


@dataclass(frozen=True)
class StepScene:
    """What the simulator needs to re-create one measured step."""

    step_id: str
    procedure: str
    target: str
    target_params: dict[str, Any]
    wall_distance_mm: float | None  # stage lab: camera-wall distance (the measurement's reference)
    reference: str  # "laser", "stage" or "robot": which nuisance offset group the step belongs to
    robot_angle_deg: float | None
    robot_radius_mm: float | None
    exposure_us: float | None
    projector: bool
    #: laser-referenced steps: the camera-laser offset their reference was formed with (reference - laser reading)
    applied_offset_mm: float | None = None
    #: an offset calibration: the camera's own mean depth over its central region set ``applied_offset_mm``
    sets_offset: bool = False
    #: laser-referenced steps: the standard uncertainty (mm) of the reference of this step alone, the laser's
    #: repeatability on the mean of its readings (``laser_step_uncertainty``; 0 for other steps)
    reference_uncertainty_mm: float = 0.0


@dataclass(frozen=True)
class Observation:
    scene: StepScene
    z: np.ndarray  # (h, w) binned stack-mean z, NaN where the bin has too few valid pixels
    z_var: np.ndarray  # variance of the binned mean
    intensity: np.ndarray  # binned stack-mean intensity
    intensity_var: np.ndarray  # variance of the binned mean intensity
    valid_fraction: np.ndarray  # share of the bin's pixels whose stack mean is valid
    times_s: np.ndarray  # device time of the frames used, s
    noise_mm: np.ndarray  # temporal std of the depth per pixel, pooled over the bin (NaN: not measured)
    noise_dof: np.ndarray  # its effective degrees of freedom, m (n - 1) / max(1, local correlation ratio)
    valid_rate: np.ndarray  # fraction of valid pixel-frames of the bin
    correlation: np.ndarray  # variance of the bin mean over the per-pixel variance / m (NaN: not measured)
    n_frames: int
    bin_px: int

    @property
    def pixel_frames(self) -> int:
        """Pixel-frames of one bin: bin_px^2 n."""
        return self.bin_px * self.bin_px * self.n_frames


def step_scene(step: StepRecord) -> StepScene | None:
    """The step's scene, or None when the simulator has no scene for its target."""
    a = step.attrs
    target = str(a.get("target", ""))
    if target not in STAGE_TARGETS and target not in PLATE_MATERIALS:
        return None
    params = json.loads(a.get("target_json", "{}") or "{}")
    settings = json.loads(a.get("settings_json", "{}") or "{}")
    reference = finite_or_none(a.get("reference_distance_mm"))
    nominal = finite_or_none(a.get("distance_mm"))
    laser = finite_or_none(a.get("laser_distance_mm"))
    if target in PLATE_MATERIALS:
        group, wall = "robot", None
    elif reference is not None and a.get("reference_source") == "laser":
        group, wall = "laser", reference
    else:
        group, wall = "stage", reference if reference is not None else nominal
    if target in STAGE_TARGETS and wall is None:
        return None
    return StepScene(
        step_id=step.step_id,
        procedure=str(a.get("procedure", "")),
        target=target,
        target_params=params,
        wall_distance_mm=wall,
        reference=group,
        robot_angle_deg=finite_or_none(a.get("robot_angle_deg")),
        robot_radius_mm=finite_or_none(a.get("robot_radius_mm")) or finite_or_none(params.get("radius_mm")),
        exposure_us=finite_or_none(a.get("exposure_us")),
        projector=bool(settings.get("projector", settings.get("emitter", True))),
        applied_offset_mm=reference - laser if group == "laser" and reference is not None and laser is not None
        else None,
        sets_offset=finite_or_none(a.get("camera_laser_offset_mm")) is not None,
        reference_uncertainty_mm=laser_step_uncertainty(a) if group == "laser" else 0.0,
    )


def bin_mean(values: np.ndarray, bin_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean of the finite values in each bin_px x bin_px bin, and their count (image cropped to whole bins)."""
    h, w = values.shape[0] // bin_px * bin_px, values.shape[1] // bin_px * bin_px
    v = values[:h, :w].reshape(h // bin_px, bin_px, w // bin_px, bin_px)
    ok = np.isfinite(v)
    count = ok.sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, np.where(ok, v, 0.0).sum(axis=(1, 3)) / count, np.nan)
    return mean, count


def noise_statistics(z: np.ndarray, bin_px: int) -> tuple[np.ndarray, ...]:
    """Per bin of an (n, H, W) depth stack: the pooled temporal std, its degrees of freedom, the valid
    fraction of the pixel-frames, the correlation ratio, and its two sums (the variance of the frame's bin
    mean and the per-pixel variance / m, for pooling). The sums over the stack are one compiled pass
    (labctl/reconcile/bin_noise.py)."""
    n = z.shape[0]
    m, mean_var, between, valid_rate = bin_noise(np.ascontiguousarray(z), bin_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = (m >= 2) & (n >= 2) & (mean_var > 0)
        independent = np.where(ok, mean_var / m, np.nan)
        between = np.where(ok, between, np.nan)
        return (np.where(ok, np.sqrt(mean_var), np.nan), m * (n - 1), valid_rate, between / independent,
                between, independent)


def _pooled_ratio(between: np.ndarray, independent: np.ndarray) -> np.ndarray:
    """The correlation ratio pooled over each bin and its eight neighbours (the step's pooled ratio where none
    of them is measured, 1 where no bin of the step is)."""
    b, i = np.nan_to_num(between), np.nan_to_num(independent)
    sb = sum(np.roll(np.roll(np.pad(b, 1), dy, 0), dx, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1))[1:-1, 1:-1]
    si = sum(np.roll(np.roll(np.pad(i, 1), dy, 0), dx, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1))[1:-1, 1:-1]
    step = float(b.sum() / i.sum()) if i.sum() > 0 else 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(si > 0, sb / si, step)


@dataclass(frozen=True)
class StepStack:
    """What the observation of a step reads of it: its first frames of z and intensity, and their times."""

    z: np.ndarray  # (n, H, W)
    intensity: np.ndarray  # (n, H, W) float32
    times_s: np.ndarray  # (n,) device time, s (empty when the step has none)


def _read_frames(step: StepRecord, channel: str, n: int, buffers: dict[str, np.ndarray]) -> np.ndarray:
    """The first ``n`` frames of the step's ``channel``, read into ``buffers[channel]`` (a fresh buffer only when
    the shape or type differs from the last step's: reading into a used one spares the kernel zeroing the fresh
    pages of a new array for every stack)."""
    dataset = step.group[channel]
    shape = (n, *dataset.shape[1:])
    out = buffers.get(channel)
    if out is None or out.shape != shape or out.dtype != dataset.dtype:
        out = buffers[channel] = np.empty(shape, dataset.dtype)
    dataset.read_direct(out, source_sel=np.s_[:n])
    return out


def _frames_and_times(step: StepRecord, max_frames: int) -> tuple[int, np.ndarray]:
    """How many of the step's frames are used (its first ``max_frames``), and their times."""
    n = min(int(step.group["z"].shape[0]), max_frames)
    return n, np.asarray(step.group["timestamp"][:n], float) if "timestamp" in step.group else np.zeros(0)


def read_stack(step: StepRecord, buffers: dict[str, np.ndarray], max_frames: int = MAX_FRAMES) -> StepStack:
    """The step's first ``max_frames`` frames of z and intensity (read into ``buffers``, which the next read into
    them overwrites) and their times."""
    n, times = _frames_and_times(step, max_frames)
    return StepStack(_read_frames(step, "z", n, buffers),
                     _read_frames(step, "intensity", n, buffers).astype(np.float32, copy=False), times)


def held_stack(step: StepRecord, held: Callable[[str], np.ndarray], max_frames: int = MAX_FRAMES) -> StepStack:
    """What :func:`read_stack` reads of a step, from its stacks as a run that keeps no frames in its file hands
    them over (``held``: a channel's stack; ``RunWriter.frame_sink``)."""
    n, times = _frames_and_times(step, max_frames)
    return StepStack(held("z")[:n], held("intensity")[:n].astype(np.float32, copy=False), times)


def observe(scene: StepScene, stack: StepStack, bin_px: int) -> Observation:
    """Binned stack statistics of one step from its frames ``stack`` (``read_stack``): the bin means of
    ``metrics.stack.stack_stats``' per-pixel means and variances of the mean (``binned_stack_stats``, the numbers
    of ``bin_mean`` over ``stack_stats``' arrays), and the depth noise's statistics (``noise_statistics``)."""
    n = stack.z.shape[0]
    z_mean, count, var_sum = binned_stack_stats(stack.z, bin_px)
    valid_fraction = count / float(bin_px * bin_px)
    keep = valid_fraction >= 0.5
    noise, dof, valid_rate, correlation, between, independent = noise_statistics(stack.z, bin_px)
    pooled = _pooled_ratio(between, independent)
    with np.errstate(invalid="ignore", divide="ignore"):
        z_var = np.where(keep, var_sum / np.maximum(count, 1) * pooled, np.nan)
    i_mean, i_count, i_var_sum = binned_stack_stats(stack.intensity, bin_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        i_var = i_var_sum / np.maximum(i_count, 1)
    return Observation(scene, np.where(keep, z_mean, np.nan), z_var, i_mean, i_var, valid_fraction, stack.times_s,
                       noise, dof / np.maximum(pooled, 1.0), valid_rate, correlation, n, bin_px)


def choose_bin(width: int, height: int, target_width: int = 48) -> int:
    """The divisor of both sensor sides closest to ``width / target_width`` (so bins tile the sensor)."""
    common = math.gcd(width, height)
    divisors = [d for d in range(1, common + 1) if common % d == 0]
    goal = max(1.0, width / target_width)
    return min(divisors, key=lambda d: (abs(math.log(d / goal)), d))


class StepObserver:
    """A frame sink (``RunWriter.frame_sink``) observing the steps ``step_ids`` of a run as each is committed,
    as :func:`observe_run` observes them in its file: a null replica is observed as it is simulated, and none
    of its frames reaches the disk (labctl/reconcile/null.py)."""

    def __init__(self, bin_px: int, step_ids: Iterable[str], max_frames: int = MAX_FRAMES) -> None:
        self.bin_px = bin_px
        self.wanted = set(step_ids)
        self.max_frames = max_frames
        self._observed: dict[str, Observation] = {}

    def __call__(self, step: StepRecord, held: Callable[[str], np.ndarray]) -> None:
        if step.step_id not in self.wanted or (scene := step_scene(step)) is None:
            return
        self._observed[step.step_id] = observe(scene, held_stack(step, held, self.max_frames), self.bin_px)

    def observations(self) -> list[Observation]:
        """The steps observed, in the order a run file lists them (``RunReader.steps``)."""
        return [self._observed[step_id] for step_id in sorted(self._observed)]


def measured_best_focus(run: RunReader, records: list[StepRecord] | None = None) -> float | None:
    """The best-focus distance the run placed its ``distance_mm = "best_focus"`` steps at: such a step's recorded
    distance less the offset its campaign gives it (a Boehler star's gap); None without such a step. ``records``:
    the run's steps, where they are listed already (``run.steps()`` reads every step's attributes)."""
    text = run.attrs.get("campaign_toml", "")
    try:
        steps = {step.step_id: step for step in parse_campaign(text, f"{run.path} (stored campaign)").steps()}
    except InputError:
        return None
    for record in run.steps() if records is None else records:
        step = steps.get(record.step_id)
        distance = float(record.attrs.get("distance_mm", math.nan))
        if step is not None and step.distance_from is not None and math.isfinite(distance):
            return distance - step.distance_offset_mm
    return None


@contextmanager
def opened_run(run: str | Path | RunReader) -> Iterator[RunReader]:
    """The run file at ``run`` opened for the time of the block, or ``run`` itself where it is open already (left
    open): a reader lists its steps' attributes once (``RunReader.steps``; about 0.9 s for the 205 steps of a
    complete campaign), however many observations are made of them."""
    if isinstance(run, RunReader):
        yield run
        return
    with RunReader(run) as opened:
        yield opened


def observe_run(path: str | Path | RunReader, bin_px: int | None = None,
                max_frames: int = MAX_FRAMES) -> tuple[list[Observation], dict[str, Any], list[str]]:
    """Observations of every re-creatable step of the run at ``path`` (or open in it: ``opened_run``), the camera
    description (``skipped``: the steps left out, with the reason), and notes on skipped steps. Each step's frames
    are read while the one before is reduced (``read_ahead``: HDF5's reading and decompression on one core, into
    one set of buffers per read-ahead slot, the compiled statistics on one thread on the other:
    ``serial_kernels``)."""
    notes: list[str] = []
    with opened_run(path) as run:
        camera = run.camera
        bin_px = bin_px or choose_bin(camera.width, camera.height)
        scenes: dict[str, StepScene] = {}
        comparable = []
        skipped = []
        records = run.steps()
        for step in records:
            scene = step_scene(step)
            if scene is None:
                why = f"target {step.attrs.get('target')!r} has no simulated scene"
                notes.append(f"{step.step_id}: {why}; skipped")
                skipped.append(ExcludedStep(step=step.step_id, family="all", reason=why))
                continue
            scenes[step.step_id] = scene
            comparable.append(step)
        buffers: list[dict[str, np.ndarray]] = [{} for _ in range(SLOTS)]
        with serial_kernels():
            observations = [observe(scenes[step.step_id], stack, bin_px) for step, stack in
                            read_ahead(comparable, lambda step, slot: read_stack(step, buffers[slot], max_frames))]
        info = {
            "width": camera.width, "height": camera.height, "fov_deg": list(camera.fov_deg),
            "bin_px": bin_px, "backend": run.devices.get("camera", {}).get("backend", ""),
            "model": run.devices.get("camera", {}).get("model", ""),
            "campaign_toml": run.attrs.get("campaign_toml", ""),
            "best_focus_mm": measured_best_focus(run, records),
            "skipped": skipped,
        }
    return observations, info, notes
