"""Compiled per-frame kernels: noise, coordinates, validity and outputs in one pass.

The noise-free quantities of a step are prepared once (sim/tof.py,
sim/stereo.py); these kernels turn them into one noisy frame. At full
resolution a frame is bound by memory traffic and arithmetic width, so the
kernels work in float32, derive what they can from what they already read
(the eq. 2-9 noise from the amplitude) and take the ray slopes as a (1, W)
row and an (H, 1) column unless distortion makes them (H, W). The fastmath
flags allow contraction and approximate reciprocals but keep NaN and infinity
semantics. Outputs are preallocated; numba specializes on their dtypes. The
separable case reads the row slope once per row, so the inner loop vectorizes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

FASTMATH = {"contract", "arcp", "afn", "reassoc", "nsz"}
F32 = np.float32


@njit(inline="always", fastmath=FASTMATH)
def _tof_pixel(r0, a0, n_amp, n_range, sx, sy, k, cd, amb, drift, quantize, inv_step, step, thr, sat, scale,
               rounded_conf):  # pragma: no cover
    """The per-pixel arithmetic of ``tof_frame`` (float32)."""
    zero, half, one, two = F32(0.0), F32(0.5), F32(1.0), F32(2.0)
    b = two * a0 + amb
    sigma_a = math.sqrt(half * b)
    sigma_r = k * math.sqrt(b) / (cd * a0) if a0 > zero else zero
    a = a0 + sigma_a * n_amp
    r = r0 + sigma_r * n_range + drift
    zz = r / math.sqrt(one + sx * sx + sy * sy)
    xx = zz * sx
    yy = zz * sy
    if quantize:
        xx = np.rint(xx * inv_step) * step
        yy = np.rint(yy * inv_step) * step
        zz = np.rint(zz * inv_step) * step
    ok = (a0 > zero) & (a >= thr) & (a <= sat)
    nan = F32(np.nan)
    a = min(max(a, zero), sat)  # the intensity image clips at saturation
    c = a / sat * scale
    return (xx if ok else nan), (yy if ok else nan), (zz if ok else nan), a, (np.rint(c) if rounded_conf else c)


@njit(parallel=True, cache=True, nogil=True, fastmath=FASTMATH)
def tof_frame(range_mm, amplitude, tx, ty, bank, off_amp, off_range, noise_k, contrast, ambient, drift_mm,
              step_mm, threshold, saturation, conf_scale, x, y, z, intensity, confidence):  # pragma: no cover
    """One CW-ToF frame.

    Noise from eq. 2-9 with B = A + ambient: sigma_r = noise_k sqrt(2A + ambient) / (contrast A),
    sigma_A = sqrt((2A + ambient) / 2). amplitude_k = A + sigma_A n1; valid if
    A > 0 and threshold <= amplitude_k <= saturation; range_k = r + sigma_r n2 + drift;
    (x, y, z) = range_k unit(tx, ty, 1), rounded to ``step_mm`` if > 0, NaN where
    invalid. The intensity is the amplitude clipped to [0, saturation]; confidence
    is it relative to saturation times ``conf_scale``. ``tx``/``ty`` are a (1, W) row and an (H, 1) column, or both (H, W).
    """
    h, w = range_mm.shape
    separable = tx.shape[0] == 1
    quantize = step_mm > 0.0
    inv_step = F32(1.0 / step_mm) if quantize else F32(0.0)
    step, k, cd, amb = F32(step_mm), F32(noise_k), F32(contrast), F32(ambient)
    drift, thr, sat, scale = F32(drift_mm), F32(threshold), F32(saturation), F32(conf_scale)
    rounded_conf = conf_scale > 1.0
    for i in prange(h):
        base = i * w
        if separable:
            sy = ty[i, 0]
            for j in range(w):
                x[i, j], y[i, j], z[i, j], intensity[i, j], confidence[i, j] = _tof_pixel(
                    range_mm[i, j], amplitude[i, j], bank[off_amp + base + j], bank[off_range + base + j],
                    tx[0, j], sy, k, cd, amb, drift, quantize, inv_step, step, thr, sat, scale, rounded_conf)
        else:
            for j in range(w):
                x[i, j], y[i, j], z[i, j], intensity[i, j], confidence[i, j] = _tof_pixel(
                    range_mm[i, j], amplitude[i, j], bank[off_amp + base + j], bank[off_range + base + j],
                    tx[i, j], ty[i, j], k, cd, amb, drift, quantize, inv_step, step, thr, sat, scale, rounded_conf)


@njit(inline="always", fastmath=FASTMATH)
def _stereo_pixel(d0, sd, ok0, n_disp, n_ir, lum, sx, sy, dquant, inv_dstep, dstep, fb, drift, quantize,
                  inv_step, step, noise):  # pragma: no cover
    """The per-pixel arithmetic of ``stereo_frame`` (float32)."""
    zero, one = F32(0.0), F32(1.0)
    d = d0 + sd * n_disp
    if dquant:
        d = np.rint(d * inv_dstep) * dstep
    ok = ok0 & (d > zero)
    zz = fb / d + drift if ok else zero
    xx = zz * sx
    yy = zz * sy
    if quantize:
        xx = np.rint(xx * inv_step) * step
        yy = np.rint(yy * inv_step) * step
        zz = np.rint(zz * inv_step) * step
    nan = F32(np.nan)
    ir = max(lum + (noise * lum + one) * n_ir, zero)
    return (xx if ok else nan), (yy if ok else nan), (zz if ok else nan), ir, (one if ok else zero)


@njit(parallel=True, cache=True, nogil=True, fastmath=FASTMATH)
def stereo_frame(disparity, sigma_disp, valid, tx, ty, ir, ir_noise, bank, off_disp, off_ir, drift_mm,
                 disparity_step, focal_baseline, step_mm, x, y, z, intensity, confidence):  # pragma: no cover
    """One active-stereo frame.

    d_k = d + sigma_d n1, rounded to ``disparity_step``; z = f b / d_k + drift;
    x = z tx, y = z ty, rounded to ``step_mm`` if > 0; NaN where not ``valid``
    or d_k <= 0. The intensity is the left IR image with relative noise
    ``ir_noise`` (plus one count).
    """
    h, w = disparity.shape
    separable = tx.shape[0] == 1
    quantize = step_mm > 0.0
    dquant = disparity_step > 0.0
    inv_step = F32(1.0 / step_mm) if quantize else F32(0.0)
    inv_dstep = F32(1.0 / disparity_step) if dquant else F32(0.0)
    step, dstep, fb, drift, noise = F32(step_mm), F32(disparity_step), F32(focal_baseline), F32(drift_mm), F32(ir_noise)
    for i in prange(h):
        base = i * w
        if separable:
            sy = ty[i, 0]
            for j in range(w):
                x[i, j], y[i, j], z[i, j], intensity[i, j], confidence[i, j] = _stereo_pixel(
                    disparity[i, j], sigma_disp[i, j], valid[i, j], bank[off_disp + base + j],
                    bank[off_ir + base + j], ir[i, j], tx[0, j], sy, dquant, inv_dstep, dstep, fb, drift,
                    quantize, inv_step, step, noise)
        else:
            for j in range(w):
                x[i, j], y[i, j], z[i, j], intensity[i, j], confidence[i, j] = _stereo_pixel(
                    disparity[i, j], sigma_disp[i, j], valid[i, j], bank[off_disp + base + j],
                    bank[off_ir + base + j], ir[i, j], tx[i, j], ty[i, j], dquant, inv_dstep, dstep, fb, drift,
                    quantize, inv_step, step, noise)
