"""The depth noise's statistics per bin of a stack, in one compiled pass (labctl/reconcile/observe.py).

Per ``bin_px`` x ``bin_px`` bin of an (n, H, W) depth stack (NaN = invalid):
the pixels valid in every frame (m of them), each one's deviations from its
own stack mean, their pooled temporal variance, the variance over the stack of
the frame's mean deviation, and the fraction of valid pixel-frames. The pass
keeps numpy's order of summation (frames one after the other, the bin's
pixels by numpy's pairwise summation), so that it gives the numbers of the
array formulation bit for bit: over the frames ``sum(axis=0)`` of an array
adds frame after frame, over a bin's pixels ``sum(axis=-1)`` adds blocks of
eight partial sums (``_pairwise_sum``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: numpy's block of pairwise summation (``PW_BLOCKSIZE`` of its loops_utils.h): below it, eight running sums
PAIRWISE_BLOCK = 128


@njit(cache=True, nogil=True)
def _block_sum(a: np.ndarray, start: int, n: int) -> float:  # pragma: no cover - compiled
    """Sum of ``a[start:start + n]``, n at most ``PAIRWISE_BLOCK``, in numpy's order: eight running sums."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[start + i]
        return res
    r0, r1, r2, r3 = a[start], a[start + 1], a[start + 2], a[start + 3]
    r4, r5, r6, r7 = a[start + 4], a[start + 5], a[start + 6], a[start + 7]
    i = 8
    while i < n - n % 8:
        r0 += a[start + i]
        r1 += a[start + i + 1]
        r2 += a[start + i + 2]
        r3 += a[start + i + 3]
        r4 += a[start + i + 4]
        r5 += a[start + i + 5]
        r6 += a[start + i + 6]
        r7 += a[start + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[start + i]
        i += 1
    return res


# numba's cache notices a change to a compiled function only in its own file: after changing this one, delete the
# cache of the kernels in labctl/reconcile/bin_moments.py that call it (__pycache__/*.nbi, *.nbc there), or they
# keep the old code
@njit(cache=True, nogil=True, inline="always")
def _pairwise_sum(a: np.ndarray, start: int, n: int, nodes: np.ndarray,
                  left: np.ndarray) -> float:  # pragma: no cover - compiled
    """Sum of ``a[start:start + n]`` in numpy's pairwise order (``pairwise_sum`` of numpy's loops_utils.h: halves,
    each cut to a multiple of eight, down to blocks of at most ``PAIRWISE_BLOCK``). The recursion runs on an
    explicit stack (``nodes``: start, length and stage of each open half; ``left``: its first half's sum), as
    numba's cache does not keep recursive functions. Inlined: a call costs as much as a block's sum."""
    if n <= PAIRWISE_BLOCK:  # one block: no stack to set up
        return _block_sum(a, start, n)
    top = 0
    nodes[0, 0], nodes[0, 1], nodes[0, 2] = start, n, 0
    returned = 0.0
    while True:
        s, c = nodes[top, 0], nodes[top, 1]
        if c <= PAIRWISE_BLOCK:
            returned = _block_sum(a, s, c)
            top -= 1
        else:
            half = c // 2
            half -= half % 8
            stage = nodes[top, 2]
            if stage < 2:
                if stage == 1:
                    left[top] = returned
                nodes[top, 2] = stage + 1
                top += 1
                nodes[top, 0], nodes[top, 1], nodes[top, 2] = (s, half, 0) if stage == 0 else (s + half, c - half, 0)
                continue
            returned = left[top] + returned
            top -= 1
        if top < 0:
            return returned


#: open halves of ``_pairwise_sum``: enough for any bin (2^64 pixels)
STACK_DEPTH = 64


@njit(parallel=True, cache=True, nogil=True)
def bin_noise(z: np.ndarray, bin_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                     np.ndarray]:  # pragma: no cover - compiled
    """Per bin of an (n, H, W) stack (cropped to whole bins): the pixels valid in every frame (m), the mean of
    their sample variances (NaN where m is 0), the variance over the frames of their mean deviation from their
    own stack means (n - 1 in both denominators, at least 1), and the fraction of valid pixel-frames.

    A row of bins at a time: the per-pixel sums over the frames run along the strip's whole rows (vectorized over
    the columns, each pixel's frames still added one after the other), then each bin's pixels are gathered in
    their order (row after row of the bin) for numpy's pairwise sums."""
    n, height, width = z.shape
    h, w = height // bin_px, width // bin_px
    m_px = bin_px * bin_px
    cols = w * bin_px
    full_count = np.zeros((h, w), np.int64)
    mean_var = np.empty((h, w))
    between = np.empty((h, w))
    valid_rate = np.empty((h, w))
    denominator = max(n - 1, 1)
    for by in prange(h):
        finite = np.zeros((bin_px, cols), np.int64)
        total = np.zeros((bin_px, cols))
        full = np.empty((bin_px, cols), np.bool_)
        centre = np.empty((bin_px, cols))
        squares = np.zeros((bin_px, cols))
        gathered = np.empty((w, m_px))
        frame_squares = np.zeros(w)
        nodes = np.empty((STACK_DEPTH, 3), np.int64)
        left = np.empty(STACK_DEPTH)
        for k in range(n):
            for dy in range(bin_px):
                row = z[k, by * bin_px + dy]
                for x in range(cols):
                    v = np.float64(row[x])
                    finite[dy, x] += 1 if v - v == 0.0 else 0
                    total[dy, x] += v
        for dy in range(bin_px):
            for x in range(cols):
                full[dy, x] = finite[dy, x] == n
                centre[dy, x] = total[dy, x] / n
        m = np.zeros(w, np.int64)
        for bx in range(w):
            counted = 0
            for dy in range(bin_px):
                for dx in range(bin_px):
                    counted += finite[dy, bx * bin_px + dx]
                    m[bx] += 1 if full[dy, bx * bin_px + dx] else 0
            full_count[by, bx] = m[bx]
            valid_rate[by, bx] = counted / (n * m_px)
        for k in range(n):
            for dy in range(bin_px):
                row = z[k, by * bin_px + dy]
                for bx in range(w):
                    for dx in range(bin_px):
                        x = bx * bin_px + dx
                        deviation = np.float64(row[x]) - centre[dy, x] if full[dy, x] else 0.0
                        squares[dy, x] += deviation * deviation
                        gathered[bx, dy * bin_px + dx] = deviation
            for bx in range(w):
                frame_mean = _pairwise_sum(gathered[bx], 0, m_px, nodes, left) / m[bx] if m[bx] > 0 else np.nan
                frame_squares[bx] += frame_mean * frame_mean
        for dy in range(bin_px):
            for bx in range(w):
                for dx in range(bin_px):
                    gathered[bx, dy * bin_px + dx] = squares[dy, bx * bin_px + dx] / denominator
        for bx in range(w):
            mean_var[by, bx] = _pairwise_sum(gathered[bx], 0, m_px, nodes, left) / m[bx] if m[bx] > 0 else np.nan
            between[by, bx] = frame_squares[bx] / denominator
    return full_count, mean_var, between, valid_rate
