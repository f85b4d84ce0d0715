"""Empirical corrections: what reconcile adds to the model when a structured residual matches no library effect.

Two forms, both effects of the simulator (sim/effects/empirical_range.py,
sim/effects/empirical_pixel_map.py) so that ``labctl run --sim --model``
applies them:

* ``empirical_range``: a piecewise-linear correction over the range, with
  ``RANGE_KNOTS`` knots spread evenly over the compared ranges;
* ``empirical_pixel_map``: a bilinear correction over the sensor on a
  ``MAP_NODES`` (columns x rows) node grid.

Both are linear in their node values, so they are fitted in closed form:
the hat-function columns (change of the depth residual per mm at one node,
times z / range for a ToF ray) are profiled like every candidate signature
and solved by ridge-regularized least squares (the part the lab's nuisance
explains, e.g. a constant, is left at the minimum-norm solution).
"""

from __future__ import annotations

import numpy as np

from labctl.reconcile.candidates import Context
from labctl.reconcile.results import Parameters
from sim.effects import empirical_pixel_map, empirical_range
from sim.effects.empirical_pixel_map import node_coordinates

RANGE_KNOTS = 13  # set by hand: 300 mm apart over a 0.4-4 m sweep, fewer knots than the sweep has steps
MAP_NODES = (13, 9)  # set by hand: nodes 1/12 of the width and 1/8 of the height apart, near-square cells at 4:3
RIDGE = 1e-6  # relative to the normal matrix's mean diagonal: numerical only, keeps the nuisance directions solvable


def _hats(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(rows, knots): the piecewise-linear interpolation weights of ``x`` at ``knots`` (held beyond the ends)."""
    eye = np.eye(len(knots))
    return np.column_stack([np.interp(x, knots, eye[k]) for k in range(len(knots))])


def _solve(ctx: Context, r: np.ndarray, depth_columns: np.ndarray) -> np.ndarray:
    """The least-squares coefficients of ``depth_columns`` (stacked depth rows x forms), profiled and whitened, for
    the whitened residual ``r`` (``Layout.profiled``). The forms leave the intensity and the statistics alone, so
    only the depth rows enter: a pixel map's 117 columns over every row of a complete campaign at the test size
    took 2.7 GB, over the depth rows 0.3 GB."""
    lay = ctx.lay
    columns = np.empty(depth_columns.shape)
    for j in range(depth_columns.shape[1]):
        columns[:, j] = lay.profiled_depth(np.nan_to_num(depth_columns[:, j]))
    a = columns.T @ columns
    a += RIDGE * np.trace(a) / len(a) * np.eye(len(a))
    return np.linalg.solve(a, columns.T @ r[:len(columns)])


def fit_range(ctx: Context, r: np.ndarray) -> Parameters:
    """``empirical_range`` parameters fitted to the profiled, whitened residual ``r``."""
    ranges = ctx.z_rows("range_mm")
    ok = np.isfinite(ranges)
    knots = np.linspace(float(ranges[ok].min()), float(ranges[ok].max()), RANGE_KNOTS)
    hats = _hats(np.where(ok, ranges, knots[0]), knots) * np.nan_to_num(ctx.z_rows("z_per_range"))[:, None]
    coef = _solve(ctx, r, hats)
    return {"range_mm": [round(float(k), 2) for k in knots], "correction_mm": [round(float(c), 4) for c in coef]}


def fit_pixel_map(ctx: Context, r: np.ndarray) -> Parameters:
    """``empirical_pixel_map`` parameters fitted to the profiled, whitened residual ``r``."""
    nx, ny = MAP_NODES
    h, w = ctx.predictions[0].z.shape
    u = np.broadcast_to(node_coordinates(nx, w)[None, :], (h, w))
    v = np.broadcast_to(node_coordinates(ny, h)[:, None], (h, w))
    # bilinear weight of every node at every bin (the same on every step)
    weights = [np.clip(1 - np.abs(u - i), 0, None) * np.clip(1 - np.abs(v - j), 0, None)
               for j in range(ny) for i in range(nx)]
    columns = np.column_stack([ctx.lay.stack_z([wt] * len(ctx.predictions)) for wt in weights])
    columns *= np.nan_to_num(ctx.z_rows("z_per_range"))[:, None]
    coef = _solve(ctx, r, columns)
    grid = coef.reshape(ny, nx)
    return {"correction_mm": [[round(float(c), 4) for c in row] for row in grid]}


RANGE, PIXEL_MAP = empirical_range.EFFECT.name, empirical_pixel_map.EFFECT.name
FORMS = {RANGE: fit_range, PIXEL_MAP: fit_pixel_map}
#: the form to try first for a residual carried by an axis
FIRST_FORM = {"distance": RANGE, "row": PIXEL_MAP, "column": PIXEL_MAP, "radius": PIXEL_MAP}
