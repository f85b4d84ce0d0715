"""Temporal noise for simulated frames, fast and reproducible.

Drawing two fresh Gaussian samples per pixel and frame costs more than the
whole frame budget (10x the AM-T100's 60 fps at 640 x 480). Instead a run
draws one bank of ``BANK_SIZE`` standard-normal samples (standardized to mean
0, variance 1) from the seed's own stream, and frame k of step s reads
contiguous slices of it starting at offsets drawn from the stream of (seed,
s, k). Within a frame all samples are distinct; a pixel's samples in two
frames coincide only if their offsets do (probability 1 / BANK_SIZE per pair
of frames), so per-pixel temporal statistics are those of independent noise.
Everything depends only on (seed, step, frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from sim.seeding import stream

BANK_SIZE = 1 << 21


@dataclass(frozen=True)
class NoiseBank:
    samples: np.ndarray  # BANK_SIZE + pixels * channels, so no slice needs to wrap
    pixels: int
    channels: int

    def offsets(self, seed: int, step_index: int, frame: int) -> np.ndarray:
        """Start offsets of the ``channels`` slices used by ``frame``."""
        rng = stream(seed, step_index, "camera", frame)
        return rng.integers(0, BANK_SIZE, size=self.channels)


@lru_cache(maxsize=8)
def make_bank(seed: int, pixels: int, channels: int) -> NoiseBank:
    """The run's bank of standard-normal samples (cached: drawing it takes tens of ms)."""
    rng = stream(seed, 0, "noise_bank")
    core = rng.standard_normal(BANK_SIZE, dtype=np.float32)
    core = (core - core.mean()) / core.std()
    tail = core[: pixels * channels]
    return NoiseBank(np.concatenate([core, tail]).astype(np.float32), pixels, channels)
