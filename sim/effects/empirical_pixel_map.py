"""empirical_pixel_map: a low-order range correction over the sensor fitted by ``labctl reconcile``.

Delta r(u, v) = bilinear interpolation of the node grid ``correction_mm``
(rows of nodes top to bottom, each row left to right) at the pixel's
normalized position u = (col - (W - 1) / 2) / (W / 2), v = (row - (H - 1) / 2)
/ (H / 2); the nodes span -1 ... 1 evenly on both axes, so the same map
serves any binning of the sensor. ToF: added to the range along the ray;
stereo: to z. Not a physical law: reconcile adds it when a residual follows
the pixel position but no library effect explains it (docs/reconcile.md).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator
from scipy import ndimage

from sim.effects.base import Effect, EffectParams


class Params(EffectParams):
    correction_mm: list[list[float]] = Field(default_factory=lambda: [[0.0]], description="node grid, mm")

    @model_validator(mode="after")
    def _grid(self) -> Params:
        grid = self.correction_mm
        if not grid or not grid[0] or any(len(r) != len(grid[0]) for r in grid):
            raise ValueError("correction_mm must be a non-empty rectangular grid (a list of equal rows)")
        if not np.all(np.isfinite(grid)) or np.max(np.abs(grid)) > 1000.0:
            raise ValueError("correction_mm must be finite and within +-1000 mm")
        return self


def node_coordinates(n_nodes: int, n_pixels: int) -> np.ndarray:
    """Each pixel's fractional node index along one axis (0 ... n_nodes - 1)."""
    u = (np.arange(n_pixels) - (n_pixels - 1) / 2) / (n_pixels / 2)
    return (u + 1) / 2 * (n_nodes - 1)


def correction(shape: tuple[int, int], p: Params) -> np.ndarray:
    """The (H, W) correction map of a sensor of ``shape``."""
    grid = np.asarray(p.correction_mm, float)
    rows = node_coordinates(grid.shape[0], shape[0])
    cols = node_coordinates(grid.shape[1], shape[1])
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    return ndimage.map_coordinates(grid, [rr, cc], order=1, mode="nearest")


def apply(range_mm: np.ndarray, p: Params) -> np.ndarray:
    return range_mm + correction(range_mm.shape, p)


EFFECT = Effect(
    "empirical_pixel_map",
    ("tof", "stereo"),
    Params,
    "fitted by labctl reconcile (empirical, no physical source)",
    order=91,
    on_range=lambda values, p, _: apply(values, p),
)
