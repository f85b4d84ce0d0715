"""Per-pixel statistics of a stack of frames (docs/metrics.md, Stacks).

"Mean" is the per-pixel mean over the stack ignoring the frames in which that
pixel is invalid (NaN); a pixel valid in fewer than half of the frames is
invalid. Repeatability is the per-pixel sample standard deviation (ISO 5725-2,
Thesis 2024, 2.1.3), with n - 1 in the denominator.

The statistics are computed in one pass over the stack by a compiled kernel
(numba): evaluating a 640 x 480 x 100 stack must cost less than reading it
from the run file (see bench/evaluation.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit, prange


@dataclass(frozen=True)
class StackStats:
    """Per-pixel mean, standard deviation and valid-frame count of an (N, H, W) stack."""

    mean: np.ndarray
    std: np.ndarray
    count: np.ndarray
    n_frames: int

    @property
    def valid(self) -> np.ndarray:
        """Pixels valid in at least half of the frames (and in two, for a std)."""
        return (2 * self.count >= self.n_frames) & (self.count >= min(2, self.n_frames))


@njit(cache=True, nogil=True, inline="always")
def _take(value: float, ref: float, c: float, s: float, ss: float) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """A pixel's valid count, sum and sum of squares of deviations from ``ref`` with one frame's ``value`` (NaN
    counts as no frame) taken in; a select, no branch, so that the loop over columns is vectorized."""
    ok = value == value
    d = value - ref if ok else 0.0
    return c + (1.0 if ok else 0.0), s + d, ss + d * d


# numba's cache notices a change to a compiled function only in its own file: after changing this one, delete the
# cache of the kernels in labctl/reconcile/bin_moments.py that call it (__pycache__/*.nbi, *.nbc there), or they
# keep the old code
@njit(cache=True, nogil=True)
def row_moments(stack: np.ndarray, i: int, count: np.ndarray, mean: np.ndarray,
                m2: np.ndarray) -> None:  # pragma: no cover - compiled
    """Row ``i`` of an (n, H, W) stack in one pass: each pixel's valid count, mean and sum of squared deviations
    into ``count``, ``mean`` and ``m2`` (length W; NaN mean and m2 where no frame is valid).

    The frame loop is vectorized over columns, four frames at a time: each
    pixel's sums are loaded and stored once per four frames (the loads and
    stores, not the arithmetic, bound the pass), the frames still taken in one
    by one, in order. Values are shifted by the pixel's first valid value and
    accumulated in float64, so the sum of squares does not cancel.

    Examples
    --------
    A row of two pixels over three frames: one seen as 1, 2, 3 (mean 2, squared deviations 2), one valid in none.

    >>> stack = np.array([[[1.0, np.nan]], [[2.0, np.nan]], [[3.0, np.nan]]])
    >>> count, mean, m2 = np.zeros(2, np.int64), np.zeros(2), np.zeros(2)
    >>> row_moments(stack, 0, count, mean, m2)
    >>> count.tolist(), mean.tolist(), m2.tolist()
    ([3, 0], [2.0, nan], [2.0, nan])
    """
    n, _, w = stack.shape
    c = np.zeros(w)
    s = np.zeros(w)
    ss = np.zeros(w)
    ref = np.zeros(w)
    for j in range(w):
        for k in range(n):  # the first valid frame (almost always frame 0)
            v0 = np.float64(stack[k, i, j])
            if v0 == v0:
                ref[j] = v0
                break
    k = 0
    while k + 4 <= n:
        f0, f1, f2, f3 = stack[k, i], stack[k + 1, i], stack[k + 2, i], stack[k + 3, i]
        for j in range(w):
            r = ref[j]
            cj, sj, ssj = _take(np.float64(f0[j]), r, c[j], s[j], ss[j])
            cj, sj, ssj = _take(np.float64(f1[j]), r, cj, sj, ssj)
            cj, sj, ssj = _take(np.float64(f2[j]), r, cj, sj, ssj)
            c[j], s[j], ss[j] = _take(np.float64(f3[j]), r, cj, sj, ssj)
        k += 4
    for rest in range(k, n):
        f0 = stack[rest, i]
        for j in range(w):
            c[j], s[j], ss[j] = _take(np.float64(f0[j]), ref[j], c[j], s[j], ss[j])
    for j in range(w):
        count[j] = np.int64(c[j])
        if c[j] > 0:
            mean[j] = ref[j] + s[j] / c[j]
            m2[j] = max(ss[j] - s[j] * s[j] / c[j], 0.0)
        else:
            mean[j] = np.nan
            m2[j] = np.nan


@njit(parallel=True, cache=True, nogil=True)
def _moments(stack: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """One pass over the stack: per-pixel valid count, mean and sum of squared deviations, rows in parallel
    (:func:`row_moments`)."""
    n, h, w = stack.shape
    count = np.zeros((h, w), np.int64)
    mean = np.empty((h, w))
    m2 = np.empty((h, w))
    for i in prange(h):
        row_moments(stack, i, count[i], mean[i], m2[i])
    return count, mean, m2


def stack_stats(stack: np.ndarray) -> StackStats:
    """Mean, sample std (ddof = 1) and valid count per pixel of an (N, H, W) stack, NaN = invalid.

    Pixels failing the half-valid rule get NaN mean and std.

    Examples
    --------
    A pixel seen as 1, 2, 3 (mean 2, sample std 1) and one valid in a single frame of three (invalid).

    >>> stats = stack_stats(np.array([[[1.0, np.nan]], [[2.0, np.nan]], [[3.0, 5.0]]]))
    >>> stats.mean.tolist(), stats.std.tolist(), stats.count.tolist()
    ([[2.0, nan]], [[1.0, nan]], [[3, 1]])
    """
    if stack.ndim != 3:
        raise ValueError(f"stack must be (N, H, W), got shape {stack.shape}")
    if stack.dtype not in (np.float32, np.float64):
        stack = stack.astype(np.float32)
    count, mean, m2 = _moments(np.ascontiguousarray(stack))
    with np.errstate(invalid="ignore", divide="ignore"):
        std = np.sqrt(m2 / (count - 1))
    stats = StackStats(mean, std, count, stack.shape[0])
    bad = ~stats.valid
    mean[bad] = np.nan
    std[bad] = np.nan
    return stats


@njit(parallel=True, cache=True, nogil=True)
def _leave_group_out(stack: np.ndarray, bounds: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Per row: the groups' sums and valid counts (float64), then the mean of all frames but each group's."""
    n, h, w = stack.shape
    groups = bounds.size - 1
    out = np.empty((groups, h, w))
    for i in prange(h):
        s = np.zeros((groups, w))
        c = np.zeros((groups, w))
        for g in range(groups):
            for k in range(bounds[g], bounds[g + 1]):
                for j in range(w):
                    v = np.float64(stack[k, i, j])
                    if v == v:
                        s[g, j] += v
                        c[g, j] += 1.0
        # the groups added in order, as sum(axis=0) adds them (written out: numba takes seconds to compile an axis
        # sum)
        total_s = np.zeros(w)
        total_c = np.zeros(w)
        for g in range(groups):
            for j in range(w):
                total_s[j] += s[g, j]
                total_c[j] += c[g, j]
        for g in range(groups):
            kept = n - (bounds[g + 1] - bounds[g])
            for j in range(w):
                count = total_c[j] - c[g, j]
                if 2.0 * count >= kept and count >= min(2, kept) and count > 0:
                    out[g, i, j] = (total_s[j] - s[g, j]) / count
                else:
                    out[g, i, j] = np.nan
    return out


def leave_group_out_means(stack: np.ndarray, groups: Sequence[range]) -> np.ndarray:
    """(G, H, W) per-pixel means of an (N, H, W) stack (NaN = invalid) without each of the G groups of frames
    ``groups`` (contiguous, in order, covering the stack: ``metrics.uncertainty.contiguous_groups``), the
    replicates of a delete-a-group jackknife of the stack mean. One pass over the stack: per group the sum and
    the valid count of every pixel; a replicate's pixel is NaN where it fails the rule of :func:`stack_stats`
    over the frames kept (valid in at least half of them and in two).

    Examples
    --------
    Four frames in two groups: one pixel seen as 1, 2, 3, 6 and one valid in the last frame only.

    >>> stack = np.array([[[1.0, np.nan]], [[2.0, np.nan]], [[3.0, np.nan]], [[6.0, 5.0]]])
    >>> leave_group_out_means(stack, [range(0, 2), range(2, 4)]).tolist()
    [[[4.5, nan]], [[1.5, nan]]]
    """
    if stack.ndim != 3:
        raise ValueError(f"stack must be (N, H, W), got shape {stack.shape}")
    if [k for g in groups for k in g] != list(range(stack.shape[0])):
        raise ValueError(f"groups {list(groups)} are not contiguous groups of the stack's {stack.shape[0]} frames")
    bounds = np.array([g[0] for g in groups] + [stack.shape[0]], dtype=np.int64)
    if stack.dtype not in (np.float32, np.float64):
        stack = stack.astype(np.float32)
    return _leave_group_out(np.ascontiguousarray(stack), bounds)


def central_roi(height: int, width: int, fraction: float = 0.1) -> tuple[slice, slice]:
    """Centred region covering ``fraction`` of each image dimension (at least 1 px).

    Examples
    --------
    >>> central_roi(480, 640)  # 48 x 64 px in the middle
    (slice(216, 264, None), slice(288, 352, None))
    """
    rh, rw = max(1, round(height * fraction)), max(1, round(width * fraction))
    top, left = (height - rh) // 2, (width - rw) // 2
    return slice(top, top + rh), slice(left, left + rw)


class RoiMean:
    """Streaming mean of a region over a stack: per-pixel stack means, then their mean.

    Used while frames are being recorded (e.g. the camera-laser offset), so the
    stack never has to be read back.
    """

    def __init__(self, roi: tuple[slice, slice], n_frames: int) -> None:
        self.roi = roi
        self.n_frames = n_frames
        self._sum: np.ndarray | None = None
        self._count: np.ndarray | None = None

    def add(self, frame: np.ndarray) -> None:
        """Take in the ROI of one frame (NaN = invalid).

        Examples
        --------
        Only the ROI's pixels count, here the first of two.

        >>> roi = RoiMean((slice(0, 1), slice(0, 1)), n_frames=2)
        >>> roi.add(np.array([[1.0, 100.0]]))
        >>> roi.add(np.array([[3.0, 100.0]]))
        >>> roi.value()
        2.0
        """
        part = np.asarray(frame[self.roi], dtype=np.float64)
        ok = ~np.isnan(part)
        if self._sum is None:
            self._sum, self._count = np.zeros(part.shape), np.zeros(part.shape, dtype=np.int64)
        self._sum += np.where(ok, part, 0.0)
        self._count += ok

    def value(self) -> float:
        """Mean over pixels valid in at least half of the frames; NaN if none.

        Examples
        --------
        Pixel means 2 (of 1 and 3) and 5 (valid in one frame of two: half of them): 3.5.

        >>> roi = RoiMean((slice(0, 1), slice(0, 2)), n_frames=2)
        >>> roi.add(np.array([[1.0, np.nan]]))
        >>> roi.add(np.array([[3.0, 5.0]]))
        >>> roi.value()
        3.5
        """
        if self._sum is None or self._count is None:
            return float("nan")
        good = 2 * self._count >= self.n_frames
        if not good.any():
            return float("nan")
        return float(np.mean(self._sum[good] / self._count[good]))
