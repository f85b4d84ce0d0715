"""fixed_pattern: per-pixel fixed-pattern range offset with column, row and pixel structure (CW-ToF).

Delta r(u, v) = C(u) + R(v) + P(u, v)

with u, v the pixel's column and row. Each term is piecewise constant on its
own grid of equal cells spanning the sensor, and a pixel takes the mean of the
terms over its own area:

* C: column profile, the cells of ``column_offsets_mm`` across the width plus
  random column stripes of standard deviation ``column_sigma_mm`` (one value
  per column of the ``grid_px`` sensor grid, drawn from ``seed``);
* R: row profile, ``row_offsets_mm`` down the height plus ``row_sigma_mm``
  random row stripes;
* P: a random per-pixel map of standard deviation ``pixel_sigma_mm``.

Column-parallel readout and the modulation signal's propagation across the
pixel array give ToF sensors a fixed range error per column and row, and the
pixels' own delays and gains a per-pixel one; calibration tools store it as a
per-pixel offset table ("fixed pattern phase noise", FPPN, in the pmd/Royale
calibration; the per-pixel offset of Lindner, Schiller, Kolb & Koch 2010 and
Kahlmann, Remondino & Ingensand 2006; Fuchs & Hirzinger 2008 fit it as a
per-pixel depth correction).

Because every pixel takes the area mean of the terms, a binned camera
(bin_px x bin_px pixels merged) sees exactly the bin means of the full
sensor's pattern: the random stripes and the pixel map are drawn on
``grid_px`` (the camera's own size when not given) whatever grid samples them.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Annotated

import numpy as np
from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed
from sim.profiles import MAX_SENSOR_PX
from sim.seeding import stream

#: one cell of a column or row profile, within the +-1000 mm the empirical corrections allow too
Offset = Annotated[float, Field(ge=-1000.0, le=1000.0)]


class Params(EffectParams):
    column_offsets_mm: list[Offset] = Field(default_factory=list, description="column profile cells, mm")
    row_offsets_mm: list[Offset] = Field(default_factory=list, description="row profile cells, mm")
    column_sigma_mm: float = Field(0.0, ge=0.0, le=100.0, description="random column stripes, mm (1 sigma)")
    row_sigma_mm: float = Field(0.0, ge=0.0, le=100.0, description="random row stripes, mm (1 sigma)")
    pixel_sigma_mm: float = Field(0.0, ge=0.0, le=100.0, description="random per-pixel offsets, mm (1 sigma)")
    seed: int = Field(0, ge=0, description="seed of the random stripes and pixel map")
    grid_px: list[Annotated[int, Field(ge=1, le=MAX_SENSOR_PX)]] | None = Field(
        None, min_length=2, max_length=2, description="[width, height] the random parts are drawn on")


def cell_average(n_cells: int, n_out: int) -> np.ndarray:
    """(n_out, n_cells) matrix: the mean of a function piecewise constant on ``n_cells`` equal cells of
    [0, 1] over each of ``n_out`` equal output cells (the overlap lengths, normalized)."""
    edges_in = np.linspace(0.0, 1.0, n_cells + 1)
    edges_out = np.linspace(0.0, 1.0, n_out + 1)
    lo = np.maximum(edges_out[:-1, None], edges_in[None, :-1])
    hi = np.minimum(edges_out[1:, None], edges_in[None, 1:])
    return np.clip(hi - lo, 0.0, None) * n_out


def offset_map_mm(width: int, height: int, p: Params) -> np.ndarray:
    """The (height, width) range offset of every pixel of a ``width`` x ``height`` camera."""
    grid_w, grid_h = p.grid_px or (width, height)
    out = np.zeros((height, width))
    if p.column_offsets_mm:
        out += (cell_average(len(p.column_offsets_mm), width) @ np.asarray(p.column_offsets_mm))[None, :]
    if p.row_offsets_mm:
        out += (cell_average(len(p.row_offsets_mm), height) @ np.asarray(p.row_offsets_mm))[:, None]
    if p.column_sigma_mm > 0:
        stripes = stream(p.seed, 0, "fixed_pattern.columns").normal(0.0, p.column_sigma_mm, grid_w)
        out += (cell_average(grid_w, width) @ stripes)[None, :]
    if p.row_sigma_mm > 0:
        stripes = stream(p.seed, 0, "fixed_pattern.rows").normal(0.0, p.row_sigma_mm, grid_h)
        out += (cell_average(grid_h, height) @ stripes)[:, None]
    if p.pixel_sigma_mm > 0:
        pixels = stream(p.seed, 0, "fixed_pattern.pixels").normal(0.0, p.pixel_sigma_mm, (grid_h, grid_w))
        out += cell_average(grid_h, height) @ pixels @ cell_average(grid_w, width).T
    return out


@lru_cache(maxsize=8)
def _cached_map(width: int, height: int, params_json: str) -> np.ndarray:
    offsets = offset_map_mm(width, height, Params.model_validate_json(params_json))
    offsets.setflags(write=False)
    return offsets


def sensor_offset_map_mm(width: int, height: int, p: Params) -> np.ndarray:
    """``offset_map_mm``, computed once per camera size and parameters (read-only)."""
    return _cached_map(width, height, p.model_dump_json())


EFFECT = Effect(
    "fixed_pattern",
    ("tof",),
    Params,
    "pmd/Royale FPPN; Lindner, Schiller, Kolb & Koch 2010; Kahlmann, Remondino & Ingensand 2006; Fuchs & Hirzinger 2008",
    observed=Observed("column_row_profile", fitted=("column_offsets_mm", "row_offsets_mm")),
    order=60,
    on_range=lambda values, p, at: values + sensor_offset_map_mm(at.sensor.profile.width, at.sensor.profile.height, p),
    binned=lambda p, width, height: p if p.grid_px is not None else p.model_copy(update={"grid_px": [width, height]}),
)
