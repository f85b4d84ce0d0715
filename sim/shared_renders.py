"""Noise-free step maps shared between simulated runs of one model in one process.

A simulated step's expensive part is its noise-free maps (the scene ray-cast through the optics and blurred:
``ToFSensor.prepare``, ``StereoSensor.prepare``); its noise comes from the run's seed alone (the noise bank and
the per-frame offsets, ``sim/noise.py``). Reconcile's null replicas simulate one campaign from one model K times
with K seeds, so every replica after the first can take its maps from the first: inside :func:`shared_renders`
a simulated camera keeps the maps it makes, and takes those kept by an earlier run for the same model and step,
with its own seed's noise bank. The frames are bit-identical to those made without (tests/sim/
test_shared_renders.py).

Kept until :func:`forget` or the process ends, as many as fit in the byte budget given: the first ones made
(for a campaign run again and again, evicting the oldest would only ever drop the map needed next).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Hashable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from sim.noise import make_bank

_kept: dict[Hashable, Any] = {}
_budget = {"bytes": 0, "used": 0}


@contextmanager
def shared_renders(max_bytes: int) -> Iterator[None]:
    """Inside, simulated cameras share their noise-free step maps (kept up to ``max_bytes`` in all)."""
    before = _budget["bytes"]
    _budget["bytes"] = max_bytes
    try:
        yield
    finally:
        _budget["bytes"] = before


def active() -> bool:
    """Whether maps are shared now (inside :func:`shared_renders`)."""
    return _budget["bytes"] > 0


def take(key: Hashable, seed: int) -> Any | None:
    """The maps kept for ``key`` with the noise bank of ``seed``, or None."""
    prepared = _kept.get(key)
    if prepared is None:
        return None
    bank = prepared.bank
    return dataclasses.replace(prepared, bank=make_bank(seed, bank.pixels, bank.channels), seed=seed)


def keep(key: Hashable, prepared: Any) -> None:
    """Keep ``prepared`` (a sensor's prepared step, arrays never changed after) for ``key`` if it fits."""
    size = sum(v.nbytes for v in vars(prepared).values() if isinstance(v, np.ndarray))
    if key not in _kept and _budget["used"] + size <= _budget["bytes"]:
        _kept[key] = prepared
        _budget["used"] += size


def forget() -> None:
    """Drop every kept map."""
    _kept.clear()
    _budget["used"] = 0
