"""Deterministic random streams: a step's data depend only on the run seed and the step.

Each consumer (camera frames, laser readings, fault schedule, ...) draws from
its own stream, keyed by name, so retries, resumes and faults in one stream
never shift another.
"""

from __future__ import annotations

import zlib

import numpy as np


def stream(seed: int, step_index: int, name: str, *keys: int) -> np.random.Generator:
    """Generator for stream ``name`` of step ``step_index`` (and optional sub-keys, e.g. frame)."""
    entropy = [int(seed), int(step_index), zlib.crc32(name.encode()), *(int(k) for k in keys)]
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(entropy)))
