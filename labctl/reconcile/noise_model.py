"""The model's temporal noise, valid fraction and noise correlation of every bin, from the simulator's own laws.

The reconcile's predictor runs the camera at the bin grid (labctl/reconcile/predict.py); these are the
statistics a full-resolution pixel of that bin would show over its stack, derived from the laws the simulator
draws its frames with (sim/tof.py, sim/stereo.py, sim/kernels.py):

* ToF (Li 2014, eq. 2-9): sigma_r = k sqrt(2 A + B_ambient) / (c_d A), B_ambient = (ambient_ratio +
  background) A_ref t_exp / t_default; the depth's noise is sigma_r z / r. A pixel is valid in a frame when
  its noisy amplitude A + sigma_A n (sigma_A = sqrt((2 A + B_ambient) / 2)) lies between the confidence
  threshold and saturation: P = Phi((sat - A) / sigma_A) - Phi((thr - A) / sigma_A). The amplitude is an
  intensive quantity (the light per pixel relative to the 90 % wall at 2 m), so a binned pixel's amplitude
  is the full-resolution pixel's at the bin centre (the lens blur only moves light across edges, and bins
  near edges are not compared).
* Stereo (Thesis 2024, 2.3.2): the disparity d0 + sigma_d n is rounded to the disparity step Delta_d, with
  f b and sigma_d = s (1 + g theta^2 / (pi/2 - theta)^2) (1 + b / m) in the full sensor's pixels (b the
  background light, m the light without it), and z = f b / d; level j of the disparity grid has probability
  Phi((j + 1/2 - delta) Delta_d / sigma_d) - Phi((j - 1/2 - delta) Delta_d / sigma_d) and depth
  z0 - z0^2 / (f b) (j - delta) Delta_d (delta: where d0 sits between two levels). The depth's std is that
  of this distribution (about z^2 / (f b) sqrt(sigma_d^2 + Delta_d^2 / 12)), or, where the camera stores
  the depth in steps Delta, of its rounded values: the levels of the disparity grid are then about as far
  apart as the steps, and rounding them compresses the noise by up to 20 % (aliasing), depending on where
  the depth sits on both grids. The model averages the variance over both positions (delta and the
  output grid's offset uniform) and states the spread of ln std over them (``noise_log_spread``), which
  the comparison adds to the sampling spread. A pixel is valid where it is in
  range (a bin holds the share of its pixels within it, ``in_range_share``), the right camera sees it (its true
  disparity keeps it inside the right image) and the local IR contrast
  over the matching window, P sd_w(D) / (L + b + P mean_w(D)), reaches ``texture_threshold`` (L the lamps'
  light, P the projector's, D the dot pattern of the full sensor blurred by its optics at the step's
  distance, lens and defocus); per frame nothing else drops it. This holds where L and P are uniform over
  the window; where the smooth light's slope g (per pixel) alone would give a contrast
  |g| sqrt((w^2 - 1) / 12) / light of ``SLOPE_SHARE`` of the threshold (an oblique, distant surface), the
  valid fraction is not predicted (NaN). The contrast is modelled to about ``CONTRAST_TOLERANCE``
  (relative): the pixels within that band of the threshold may fall either way, and half their share is the
  model's uncertainty of the valid fraction (``valid_spread``), added to the validity family's sampling
  variance.
* Stereo mean: the stored depth's expectation over the same distribution, sum_j P_j round(f b / d_j + drift)
  (``stored_depth_bias``), differs from the noise-free depth by where the true disparity sits on both grids:
  the disparity levels map to depths that the output steps round each by a fixed amount, which no noise
  averages out (the noise only chooses among the levels). On a D455 at 160 x 120 (levels 2.5 mm apart at
  806 mm, sigma_d 0.8 of a level) the wall means of the simulator lie -0.28 mm (806 mm), +0.17 mm (906 mm)
  and -0.13 mm (1006 mm) from the true distance, which the expectation reproduces to 0.01 mm; it also holds
  Jensen's 1/d term, z sigma_d^2 / d^2 (0.4 mm at 4 m). A bin is the mean of its pixels' expectations over
  ``SUB_SAMPLES`` x ``SUB_SAMPLES`` points spread over it along the depth's slope; where the bin spans more
  than ``SPAN_LEVELS`` levels (a tilted plate), or where sigma_d exceeds ``LATTICE_RATIO`` levels, the
  positions average out and only Jensen's term with the disparity rounding's variance remains.
* ToF mean with output steps (``quantization``, a camera storing millimetres): each pixel stores
  round_Delta(z + sigma_z n), whose expectation sum_k k Delta P_k (P_k the normal mass within half a step of
  k Delta) differs from z by up to Delta / 2 where sigma_z is small against Delta (``tof_stored_bias``): a
  frontal wall puts every pixel at one z, so the whole step's mean sits off by where z + drift falls on the
  grid (amt100 at 400 mm: sigma_z about 0.05 mm against 1 mm steps), a bias no noise averages out, and one a
  warm-up drift moves. The bin's points are taken as for the stereo mean.
* ToF output steps (``quantization``, a camera storing millimetres) add Delta^2 / 12 where
  sigma >= Delta / 2 (Sheppard 1898; the neglected ripple is below exp(-2 pi^2 sigma^2 / Delta^2) < 1 %).
  Below sigma = Delta / 2 (both technologies) the rounded noise depends on where the true value sits on the
  grid, which the model cannot know: the bin's noise is not predicted (NaN).
* Correlation: the simulator draws every pixel's noise independently (the stereo matching window is not
  simulated as a correlation of neighbours), so the ratio of a bin mean's variance to the per-pixel
  variance / n is 1 wherever the noise is predicted.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage, special

from labctl.reconcile.finite import finite
from sim.effects import output_step_mm
from sim.sensor import SensorOptics
from sim.stereo import AMBIENT_LEVEL, DOT_DENSITY, MATCHING_WINDOW_PX, PROJECTOR_LEVEL, StereoSensor, dot_pattern
from sim.tof import IRRADIANCE_REF, ToFSensor, range_noise_mm


def _phi(x: np.ndarray) -> np.ndarray:
    return 0.5 * special.erfc(-x / math.sqrt(2.0))


def with_output_step(sigma: np.ndarray, step_mm: float) -> np.ndarray:
    """The std of a value with noise ``sigma`` stored in steps of ``step_mm``: sqrt(sigma^2 + step^2 / 12) where
    sigma >= step / 2 (Sheppard's correction), NaN below (unpredictable), sigma itself without a step."""
    if step_mm <= 0:
        return sigma
    with np.errstate(invalid="ignore"):
        return np.where(sigma >= step_mm / 2, np.sqrt(sigma**2 + step_mm**2 / 12.0), np.nan)


SUB_SAMPLES = 4  # points per axis of a bin at which the stored depth's expectation is taken (at most bin_px)
FLAT_LEVELS = 0.01  # a bin whose depth spans less than this share of a level: its centre stands for it
SPAN_LEVELS = 2.0  # a bin whose depth spans more disparity levels than this sees every position on the grids
DISPARITY_POSITIONS = 8  # where the true disparity sits between two levels of its grid
OUTPUT_OFFSETS = 16  # where the true depth sits on the output grid
SLOPE_SHARE = 0.5  # a light slope giving this share of the texture threshold's contrast: validity not predicted
CONTRAST_TOLERANCE = 0.15  # relative accuracy of the modelled matching contrast
LATTICE_RATIO = 4.0  # sigma_d / disparity step above which both roundings follow Sheppard's correction
#: the disparity levels summed: those within this many sigma_d of the true disparity (beyond, the normal tail's
#: probability, erfc(8.5 / sqrt 2) / 2 = 1e-17, weighs less than a double's rounding of the variance)
TAIL_SIGMAS = 8.5


def stored_disparity_noise(z: np.ndarray, sigma_d: np.ndarray, step_d: float, focal_baseline: float,
                           step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Std of a stereo depth whose disparity is rounded to ``step_d`` and, with ``step_mm`` > 0, stored in
    steps of ``step_mm`` (module docstring), averaged over where the true values sit on both grids; and the
    spread (std) of ln std over those positions. NaN where the noise is below half the output step. Where
    sigma_d exceeds ``LATTICE_RATIO`` disparity steps, the grids no longer alias and Sheppard's correction
    holds for both roundings."""
    scale = finite(z) ** 2 / focal_baseline
    sheppard = with_output_step(scale * np.sqrt(sigma_d**2 + step_d**2 / 12.0), step_mm)
    ratio = np.nan_to_num(sigma_d / step_d, nan=1.0)
    lattice = ratio <= LATTICE_RATIO
    std, spread = np.where(lattice, np.nan, sheppard), np.where(lattice, np.nan, 0.0)
    levels = int(math.ceil(5 * LATTICE_RATIO)) + 1
    offsets = OUTPUT_OFFSETS if step_mm > 0 else 1
    std[lattice], spread[lattice] = _lattice_noise(ratio[lattice], scale[lattice], step_d, step_mm, levels,
                                                   DISPARITY_POSITIONS, offsets, TAIL_SIGMAS)
    sigma = scale * sigma_d
    ok = np.isfinite(z) & ((step_mm <= 0) | (sigma >= step_mm / 2))
    return np.where(ok, std, np.nan), np.where(ok, spread, np.nan)


@njit(cache=True, nogil=True, error_model="numpy")  # x / 0 is inf, as in numpy (a zero disparity noise)
def _lattice_noise(ratio: np.ndarray, scale: np.ndarray, step_d: float, step_mm: float, levels: int,
                   positions: int, offsets: int, tail: float) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """Per bin: sqrt of the mean over the grid positions (``positions`` of the disparity, ``offsets`` of the
    output grid, 1 without an output step) of the variance of the depth over the disparity levels -``levels`` ...
    ``levels`` (those within ``tail`` sigma_d of the true disparity: the others hold no probability a double
    resolves), and the std of half its logarithm (``stored_disparity_noise``; compiled: reconcile predicts every
    bin of every step at each evaluation of its fits).

    Two identities cut the work. (1) The disparity's positions are symmetric about a level (delta and -delta),
    and the depth at -delta is the mirror image of the depth at delta (level j's probability and deviation those
    of level -j, negated); rounding the mirrored depth at the output grid's offset u gives the mirror of rounding
    the original at the offset 1 - u, one of the same offsets: each of the positions -delta repeats the
    variances of its mirror, so the positions delta > 0 alone, each counted twice, give the same mean and the
    same spread. (2) Over the output grid's offsets ((o + 1/2) / offsets of a step, rising by less than a step in
    all), a level's rounded depth steps up once at most, at the offset where its fraction of a step reaches the
    rounding's edge: each level's moments are added where it starts, and its step's where the step comes, and
    running sums give every offset's moments (``offsets`` plus the levels' count of additions, not their
    product)."""
    half = (positions + 1) // 2  # delta > 0 (and delta = 0 of an odd count, once)
    n_half = half * offsets
    std, spread = np.empty(ratio.size), np.empty(ratio.size)
    probs, values = np.empty(2 * levels + 1), np.empty(2 * levels + 1)
    variance, half_log = np.empty(n_half), np.empty(n_half)
    weight = np.empty(half)  # each computed position's count: its mirror's too
    cdf = np.empty(2 * levels + 2)
    m1, m2 = np.empty(offsets), np.empty(offsets)
    root2 = math.sqrt(2.0)
    start = 0.5 / offsets + 0.5  # the first offset, and the rounding's half step: floor(x + start) rounds x + u_0
    for i in range(ratio.size):
        r = ratio[i]
        reach = min(levels, int(math.ceil(tail * r + 1.0)))  # |j - delta| <= tail r, |delta| <= 1/2
        first, count = levels - reach, 2 * reach + 1
        for h in range(half):
            d = positions - half + h
            weight[h] = 1.0 if 2 * d + 1 == positions else 2.0
            delta = (d + 0.5) / positions - 0.5
            for k in range(first, first + count + 1):  # the cumulative probability at each level's lower edge
                cdf[k] = 0.5 * math.erfc(-(k - levels - 0.5 - delta) / r / root2)
            for k in range(first, first + count):
                probs[k] = cdf[k + 1] - cdf[k]
                values[k] = -scale[i] * (k - levels - delta) * step_d
            if step_mm > 0:
                m1[:] = 0.0
                m2[:] = 0.0
                for k in range(first, first + count):
                    x = values[k] / step_mm + start
                    n = math.floor(x)  # the level's rounded depth (in steps) at the first offset
                    p = probs[k]
                    m1[0] += p * n
                    m2[0] += p * n * n
                    up = int(math.ceil((1.0 - (x - n)) * offsets))  # the offset where it rounds one step up
                    if up < offsets:
                        m1[up] += p
                        m2[up] += p * (2 * n + 1)
                for o in range(offsets):
                    if o:
                        m1[o] += m1[o - 1]
                        m2[o] += m2[o - 1]
                    variance[h * offsets + o] = max(m2[o] - m1[o] * m1[o], 0.0) * step_mm * step_mm
            else:
                s1, s2 = 0.0, 0.0
                for k in range(first, first + count):
                    s1 += probs[k] * values[k]
                    s2 += probs[k] * values[k] * values[k]
                for o in range(offsets):
                    variance[h * offsets + o] = max(s2 - s1 * s1, 0.0)
        total_w, total, mean_log = 0.0, 0.0, 0.0
        for j in range(n_half):
            half_log[j] = 0.5 * np.log(variance[j])
            total_w += weight[j // offsets]
            total += weight[j // offsets] * variance[j]
            mean_log += weight[j // offsets] * half_log[j]
        mean_log /= total_w
        dev = 0.0
        for j in range(n_half):
            dev += weight[j // offsets] * (half_log[j] - mean_log) ** 2
        std[i] = math.sqrt(total / total_w)
        spread[i] = math.sqrt(dev / total_w)
    return std, spread


#: how many of its noise's standard deviations a pixel's amplitude must lie from the confidence cut and the
#: saturation for its valid probability to be 0 or 1 to double precision (Phi(-8) = 6e-16): no bin all of whose
#: pixels lie further away needs its pixels' mean
CUT_REACH_SIGMA = 8.0
#: the largest difference between a bin's valid fraction at its mean amplitude and its pixels' mean that is left
#: (a thousandth of the validity family's floor, labctl/reconcile/residuals.py): bounded by half the second
#: difference of the valid probability over the pixels' spread, P(a + h) + P(a - h) - 2 P(a), where P curves one
#: way across it
VALID_MEAN_TOLERANCE = 2e-5


#: the most points per axis at which a bin's valid probability is averaged (``group_offsets``)
VALID_POINTS = 8


def group_offsets(bin_px: int) -> np.ndarray:
    """Where along an axis a bin's valid probability is taken, about its centre in pixels: each pixel's centre
    for bins of up to ``VALID_POINTS`` pixels, else the centres of ``VALID_POINTS`` or fewer equal groups of
    pixels (the largest count that divides ``bin_px``). A group's centre is its pixels' mean position; what it
    leaves out is the spread within the group, (g^2 - 1) / 12 px^2 against the bin's (b^2 - 1) / 12: 1.2 % for
    the 640 x 480 blaze-101's bins of 16 pixels in groups of 2, whose 256 pixels cost 0.8 ms a step.

    >>> group_offsets(4).tolist(), group_offsets(16)[:2].tolist()
    ([-1.5, -0.5, 0.5, 1.5], [-7.0, -5.0])
    """
    points = max(m for m in range(1, min(bin_px, VALID_POINTS) + 1) if bin_px % m == 0)
    group = bin_px // points
    return np.arange(points) * group + (group - 1) / 2.0 - (bin_px - 1) / 2.0


def tof_noise(sensor: ToFSensor, amplitude: np.ndarray, ambient: float, z_per_range: np.ndarray) -> np.ndarray:
    """Per bin: the depth's temporal std (mm, NaN where not predicted) at the bin's ``amplitude``."""
    seen = amplitude > 0
    a = np.where(seen, amplitude, 1.0)
    sigma_z = np.where(seen, range_noise_mm(sensor.profile, a, ambient) * z_per_range, np.nan)
    return with_output_step(sigma_z, output_step_mm(sensor.effects))


def tof_valid_fraction(sensor: ToFSensor, amplitude: np.ndarray, ambient: float,
                       slopes: tuple[np.ndarray, np.ndarray] | None = None, bin_px: int = 1) -> np.ndarray:
    """Per bin: the expected valid fraction.

    A pixel-frame is valid when its amplitude, a + N(0, sigma_a^2) with sigma_a^2 = (2 a + ambient) / 2, lies
    between the confidence cut and the saturation: Phi((saturation - a) / sigma_a) - Phi((cut - a) / sigma_a).
    A bin's valid fraction is the mean of that over its ``bin_px`` x ``bin_px`` pixels, whose amplitudes differ
    where the light slopes across the bin (a tilted plate, a vignetting): ``slopes``, the amplitude's change per
    pixel down the rows and along the columns, puts the pixels at a + slope . offset. The probability is not
    linear in a, so near the cut the bin's mean amplitude gives a fraction too sharp: on a tilted plate of the
    amt100 at its test size (bins of 4 px), bins predicted 74 % valid at their mean amplitude were 69 % valid,
    those predicted 5 % were 6 %. Without ``slopes``, or where the pixels' mean cannot differ from it by more
    than ``VALID_MEAN_TOLERANCE`` (the probability as good as straight across them: most bins, far from the
    cut), the fraction at the bin's mean amplitude."""
    p = sensor.profile
    seen = amplitude > 0
    a = np.where(seen, amplitude, 1.0)
    threshold, saturation = p.confidence_threshold_ratio * sensor.a_ref, p.saturation_ratio * sensor.a_ref

    def sigma_at(amp: np.ndarray) -> np.ndarray:
        return np.sqrt((2.0 * amp + ambient) / 2.0)

    def valid_at(amp: np.ndarray) -> np.ndarray:
        sigma_a = sigma_at(amp)
        return _phi((saturation - amp) / sigma_a) - _phi((threshold - amp) / sigma_a)

    valid = valid_at(a)
    if slopes is not None and bin_px > 1:
        gy, gx = slopes
        half = (np.abs(gx) + np.abs(gy)) * (bin_px - 1) / 2.0  # the bin's pixels lie within a +- half
        reach = CUT_REACH_SIGMA * sigma_at(a + half)
        near = np.nonzero(seen & (half > 0) & ((np.abs(a - threshold) < half + reach)
                                               | (np.abs(a - saturation) < half + reach)))
        if near[0].size:  # most steps have none: a wall far above the cut
            an, hn = a[near], half[near]
            bend = valid_at(an + hn) + valid_at(np.maximum(an - hn, 0.0)) - 2.0 * valid[near]
            across = tuple(axis[np.abs(bend) > 2.0 * VALID_MEAN_TOLERANCE] for axis in near)
            offsets = group_offsets(bin_px)
            pixels = (a[across][:, None, None] + gy[across][:, None, None] * offsets[:, None]
                      + gx[across][:, None, None] * offsets[None, :])
            valid[across] = np.mean(valid_at(np.maximum(pixels, 0.0)), axis=(-2, -1))
    return np.where(seen, valid, 0.0)


def in_range_share(z: np.ndarray, low: float, high: float, bin_px: int) -> np.ndarray:
    """Per bin of the depth map ``z`` (NaN: none), the share of its ``bin_px`` x ``bin_px`` pixels whose depth lies
    within the camera's range [``low``, ``high``], the depth taken as linear across the bin with the slope between
    the bins (``np.gradient``; flat where a neighbour has none). A surface seen nearly edge-on runs through
    hundreds of millimetres within one bin: a bin whose mean lies just beyond the range still holds pixels within
    it (a quarter of a D455 bin 174 mm beyond 6 m, its depth rising 174 mm a pixel), and one just inside it
    pixels beyond.

    A map whose depths all lie further inside the range than its depth span is within it whole: each gradient
    is at most that span per bin (a difference of two of its depths over one bin, or over two bins halved), so
    no bin's pixels spread by more. Every bin with a depth then has the share 1, found without the gradients
    (most steps a fit predicts: a wall well inside the range)."""
    low_z, high_z = np.fmin.reduce(z, axis=None), np.fmax.reduce(z, axis=None)  # NaN only where no bin has one
    span = (high_z - low_z) * (1.0 + 1e-9) + 1e-9 * abs(high_z)  # a margin for the gradients' rounding
    if low_z - span >= low and high_z + span <= high:
        return np.isfinite(z).astype(float)
    if min(z.shape) > 1:
        gy, gx = (finite(g) for g in np.gradient(z, bin_px))
    else:
        gy = gx = np.zeros_like(z)
    half = (np.abs(gx) + np.abs(gy)) * (bin_px - 1) / 2.0  # the bin's pixels lie within z +- half
    with np.errstate(invalid="ignore"):
        share = ((z - half >= low) & (z + half <= high)).astype(float)  # NaN: 0
        across = np.nonzero(~(share > 0) & (z + half >= low) & (z - half <= high))  # the bins a cut runs through
    offsets = np.arange(bin_px) - (bin_px - 1) / 2.0  # the pixels' positions about the bin's centre
    pixels = (z[across][:, None, None] + gy[across][:, None, None] * offsets[:, None]
              + gx[across][:, None, None] * offsets[None, :])
    share[across] = np.mean((pixels >= low) & (pixels <= high), axis=(-2, -1))
    return share


def dot_window_stats(optics: SensorOptics, distance_mm: float, bin_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std over the matching window around every pixel of the full sensor's dot pattern as its optics
    blur it at ``distance_mm`` (``optics``: the full sensor's, with the model's effects; the blur acts on 2 x 2
    sub-pixels before each pixel integrates them, as sim/stereo.py renders it), gathered per bin: two
    (height / bin_px, width / bin_px, bin_px^2) arrays."""
    p = optics.profile
    fine = np.repeat(np.repeat(dot_pattern(p.height, p.width), 2, axis=0), 2, axis=1)
    dots = optics.blur(fine, distance_mm, 2)
    mean = ndimage.uniform_filter(dots, MATCHING_WINDOW_PX)
    std = np.sqrt(np.maximum(ndimage.uniform_filter(dots**2, MATCHING_WINDOW_PX) - mean**2, 0.0))
    h, w = p.height // bin_px, p.width // bin_px

    def per_bin(a: np.ndarray) -> np.ndarray:
        return a[:h * bin_px, :w * bin_px].reshape(h, bin_px, w, bin_px).transpose(0, 2, 1, 3).reshape(h, w, -1)

    return per_bin(mean), per_bin(std)


def stereo_statistics(sensor: StereoSensor, z: np.ndarray, true_z: np.ndarray, sigma_d: np.ndarray,
                      light: StereoLight, dot_stats: tuple[np.ndarray, np.ndarray], bin_px: int,
                      shading_slope: np.ndarray | None = None,
                      true_slope: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per bin of a binned stereo sensor with its light ``light`` (``stereo_light``) and disparity noise
    ``sigma_d`` (``disparity_noise_px``): the depth's temporal std (mm, NaN where not predicted), the spread of
    its logarithm over where the depth sits on the grids (``stored_disparity_noise``), the expected valid
    fraction of its full-resolution pixels, and that fraction's uncertainty (half the share of pixels whose
    contrast lies within ``CONTRAST_TOLERANCE`` of the threshold). ``z`` is the depth the camera reports (its
    range cut, its noise), ``true_z`` the surface's true depth: where the right camera sees the point follows
    the scene's geometry, not the camera's range error.

    ``true_slope``: per bin, ``true_z``'s slope per pixel along the rows (``predict.range_spread``): where the right
    camera's view ends (the left band of the depth map, f b / z pixels wide) each of the bin's pixel columns is
    taken at its own depth, the bin's plus the slope times its offset from the bin's centre. On the d455's plate at
    -60 deg at the image's left edge (2.2 m, its depth falling 16 mm a pixel of 160 towards the edge, the band's
    edge f b / z = 4.5-4.7 px) the band taken at the bin's mean depth missed one of its four pixel columns (25
    points of its valid fraction).

    ``shading_slope``: per bin, the relative slope per pixel, |grad S| / S, of a shading S (vignetting) that
    multiplies the IR image the matcher sees. Across the matching window S = S_0 (1 + s . x), x the pixel's offset
    from the window's centre, so the window's light L S has mean S_0 m and variance S_0^2 (sigma^2 + (sigma^2 +
    m^2) |s|^2 (w^2 - 1) / 12) (L's mean m and std sigma, x independent of L with variance (w^2 - 1) / 12 per
    axis): contrast^2 = c^2 + (1 + c^2) |s|^2 (w^2 - 1) / 12, c the contrast without it. At 40 deg off the
    D455's axis (cos^4.8, f = 104 px at 160 px) |s| = 0.039 and the shading alone gives a contrast of 0.078, more
    than the texture threshold (0.05)."""
    p = sensor.profile
    h, w = z.shape
    lamps, dots, background = light
    focal_baseline = sensor.matching_focal_baseline  # the full sensor's f b
    mean, std = dot_stats
    # a smooth light with slope g per pixel of the full sensor adds g^2 (w^2 - 1) / 12 per axis to the window's
    # variance: on an oblique surface the falling light is texture the model does not hold
    smooth = lamps + dots * DOT_DENSITY
    gy, gx = np.gradient(smooth, bin_px) if min(smooth.shape) > 1 else (np.zeros_like(smooth),) * 2
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.sqrt((gx**2 + gy**2) * (MATCHING_WINDOW_PX**2 - 1) / 12.0) / (smooth + background)
        contrast = dots[..., None] * std / (lamps[..., None] + background + dots[..., None] * mean)
    if shading_slope is not None:
        shaded = (shading_slope**2 * (MATCHING_WINDOW_PX**2 - 1) / 12.0)[..., None]
        contrast = np.sqrt(contrast**2 + (1.0 + contrast**2) * shaded)
    relative = finite(contrast) / p.texture_threshold
    textured = np.mean(relative >= 1.0, axis=-1)
    marginal = np.mean(np.abs(relative - 1.0) < CONTRAST_TOLERANCE, axis=-1)
    # the right camera sees column u of the full sensor while u - f b / z >= 0
    u = (np.arange(w)[:, None] * bin_px + np.arange(bin_px)[None, :]).astype(float)  # (w, bin_px)
    offset = np.arange(bin_px) - (bin_px - 1) / 2.0  # each pixel column's from the bin's centre
    pixel_z = true_z[..., None] + (0.0 if true_slope is None else true_slope[..., None] * offset)
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = np.mean(u[None, :, :] - focal_baseline / pixel_z >= -0.5, axis=-1)  # u_right rounded
    share = in_range_share(z, p.min_range_mm, p.max_range_mm, bin_px)
    in_range = share > 0
    valid = share * textured * inside
    valid = np.where(in_range & ~(slope <= SLOPE_SHARE * p.texture_threshold), np.nan, valid)
    sigma_z, spread = stored_disparity_noise(np.where(in_range, z, np.nan), sigma_d, p.disparity_step_px,
                                             focal_baseline, output_step_mm(sensor.effects))
    return sigma_z, spread, valid, np.where(in_range, marginal / 2, 0.0)


StereoLight = tuple[np.ndarray, np.ndarray, float]
"""Per bin: the lamps' light, the projector's light on a fully dotted pixel, and the background level."""


def stereo_light(sensor: StereoSensor, rendered, exposure_us: float, projector: bool) -> StereoLight:
    """The light of a binned stereo sensor's render (``StereoLight``) at ``exposure_us``, with or without the
    projector, as sim/stereo.py lights it before the blur."""
    gain = exposure_us / sensor.profile.exposure_us
    k = rendered.oversample
    h, w = rendered.hit_fraction.shape

    def fine_mean(a: np.ndarray) -> np.ndarray:
        return a.reshape(h, k, w, k).mean(axis=(1, 3))

    lamps = AMBIENT_LEVEL * fine_mean(rendered.passive_fine) * gain
    dots = PROJECTOR_LEVEL * fine_mean(rendered.irradiance_fine) / IRRADIANCE_REF * gain if projector \
        else np.zeros_like(lamps)
    return lamps, dots, sensor.background(exposure_us)


def disparity_noise_px(sensor: StereoSensor, rendered, light: StereoLight) -> np.ndarray:
    """Per bin of a binned stereo sensor with its light ``light`` (``stereo_light``): the disparity noise sigma_d
    in the full sensor's pixels, s (1 + g theta^2 / (pi/2 - theta)^2) (1 + b / m) as sim/stereo.py draws it
    (module docstring)."""
    p = sensor.profile
    lamps, dots, background = light
    signal = lamps + dots * sensor.dots
    theta = np.arccos(np.clip(rendered.cos_dom, 1e-6, 1.0))
    angle_term = 1.0 + p.angle_noise_gain * theta**2 / np.maximum(math.pi / 2 - theta, 1e-3) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        contrast_term = np.where(signal > 0, 1.0 + background / signal, 1.0)
    return p.noise_mm_at_2m * sensor.matching_focal_baseline / 2000.0**2 * angle_term * contrast_term


@dataclass(frozen=True)
class _BinPoints:
    """A bin grid's depth (0 where NaN) and its slope per pixel along rows (``gy``) and columns (``gx``): a bin's
    expectation is taken at its centre where it is flat, else at ``SUB_SAMPLES`` x ``SUB_SAMPLES`` points (at
    most one per pixel) spread over it along the slope."""

    z: np.ndarray
    gy: np.ndarray
    gx: np.ndarray
    bin_px: int

    @classmethod
    def of(cls, z: np.ndarray, bin_px: int) -> _BinPoints:
        gy, gx = (finite(g) for g in np.gradient(z, bin_px)) if min(z.shape) > 1 else (np.zeros_like(z),) * 2
        return cls(np.where(np.isfinite(z), z, 0.0), gy, gx, bin_px)

    @property
    def span_mm(self) -> np.ndarray:
        """How far the depth changes across a bin (mm, along both axes)."""
        return (np.abs(self.gx) + np.abs(self.gy)) * self.bin_px

    def points(self, mask: np.ndarray) -> np.ndarray:
        """The points of the bins of ``mask``: (bins, points)."""
        n = min(SUB_SAMPLES, self.bin_px)
        offsets = ((np.arange(n) + 0.5) * self.bin_px / n - self.bin_px / 2.0)  # pixels from the bin centre
        sub = (self.z[mask][:, None, None] + self.gy[mask][:, None, None] * offsets[:, None]
               + self.gx[mask][:, None, None] * offsets[None, :])
        return sub.reshape(int(mask.sum()), -1)

    def expect(self, out: np.ndarray, exact: np.ndarray, spread: np.ndarray,
               mean: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
        """``out`` with the bins of ``exact`` set to ``mean(points, mask)`` (a bin's mean over its points),
        a bin whose depth spans at most ``FLAT_LEVELS`` (``spread``, in the rounding's levels) at its centre."""
        flat = exact & (spread <= FLAT_LEVELS)  # one point stands for the bin
        sloped = exact & ~flat
        if flat.any():
            out[flat] = mean(self.z[flat][:, None], flat)
        if sloped.any():
            out[sloped] = mean(self.points(sloped), sloped)
        return out


def stored_depth_bias(z: np.ndarray, sigma_d: np.ndarray, step_d: float, focal_baseline: float, step_mm: float,
                      drift_mm: float, bin_px: int) -> np.ndarray:
    """Per bin: the mean of its pixels' expected stored depth, sum_j P_j round(f b / d_j + drift) over the
    disparity levels d_j, minus the noise-free depth z + drift (module docstring, "Stereo mean"). ``z``: the
    bins' noise-free depth (NaN where nothing is seen), ``sigma_d`` their disparity noise and ``focal_baseline``
    f b, both in the full sensor's pixels; ``step_mm`` 0 for a camera that stores no steps. 0 where z is NaN."""
    finite = np.isfinite(z)
    if not finite.any() or step_d <= 0:
        return np.zeros_like(z)
    grid = _BinPoints.of(z, bin_px)
    zz = grid.z
    with np.errstate(divide="ignore", invalid="ignore"):
        level_mm = zz**2 * step_d / focal_baseline  # depth between two disparity levels
        spread = grid.span_mm / level_mm
        sd = np.nan_to_num(sigma_d, nan=0.0, posinf=0.0)
        jensen = zz**3 * (sd**2 + step_d**2 / 12.0) / focal_baseline**2
    exact = finite & (spread <= SPAN_LEVELS) & (zz > 0) & (sd <= LATTICE_RATIO * step_d)
    return grid.expect(np.where(finite, jensen, 0.0), exact, spread,
                       lambda points, mask: _stored_mean(points, sd[mask], step_d, focal_baseline, step_mm, drift_mm))


def tof_stored_bias(z: np.ndarray, sigma_z: np.ndarray, step_mm: float, bin_px: int) -> np.ndarray:
    """Per bin: the mean of its pixels' expected stored depth, E[round_step(z + sigma_z n)], minus z (module
    docstring, "ToF mean"). ``z``: the bins' noise-free depth, drift included (NaN where nothing is seen);
    ``sigma_z`` the pixels' depth noise before the rounding. A bin whose depth spans more than ``SPAN_LEVELS``
    steps sees every position on the grid: 0 there, as where z is NaN or the camera stores no steps."""
    finite = np.isfinite(z)
    if step_mm <= 0 or not finite.any():
        return np.zeros_like(z)
    grid = _BinPoints.of(z, bin_px)
    spread = grid.span_mm / step_mm
    sd = np.nan_to_num(sigma_z, nan=0.0, posinf=0.0)
    exact = finite & (spread <= SPAN_LEVELS) & (sd <= LATTICE_RATIO * step_mm)
    return grid.expect(np.zeros_like(grid.z), exact, spread,
                       lambda points, mask: _rounded_mean(points, sd[mask], step_mm))


#: sigma / step from which ``_rounded_mean`` sums the rounding's Fourier series instead of the levels: there the
#: series' terms fall as exp(-2 pi^2 (sigma / step)^2 m^2), below 1e-17 of a step after 6 terms (m^2 > 39.1 /
#: (2 pi^2 0.25^2) = 31.7), while the levels within 6 sigma of the value number 12 sigma / step + 2 and each costs
#: an erfc; below it the levels are at most 5
FOURIER_RATIO = 0.25
#: the size, in steps, of the series' last term summed (a double's resolution of a step's fraction)
FOURIER_TAIL = 1e-17


@njit(cache=True, nogil=True)
def _rounded_mean(sub: np.ndarray, sigma: np.ndarray, step: float) -> np.ndarray:  # pragma: no cover (compiled)
    """Per bin: the mean over its sample values ``sub`` of E[round_step(v + sigma n)] - v. Below ``FOURIER_RATIO``
    sigma / step, the sum over the steps within 6 sigma of v of their normal mass times the step; above, the same
    expectation as the Fourier series of the rounding error, x - round x = sum_m (-1)^(m+1) sin(2 pi m x) / (pi m),
    whose terms a normal noise damps, E sin(2 pi m (v + sigma n) / step) = exp(-2 pi^2 m^2 sigma^2 / step^2)
    sin(2 pi m v / step) (Sheppard 1898; Widrow & Kollar 2008, ch. 4-5): step / pi sum_m (-1)^m exp(-2 pi^2 m^2
    sigma^2 / step^2) sin(2 pi m v / step) / m, its terms summed while they exceed ``FOURIER_TAIL`` of a step, the
    sines by the recurrence sin((m + 1) t) = 2 cos t sin(m t) - sin((m - 1) t)."""
    root2 = math.sqrt(2.0)
    out = np.empty(sub.shape[0])
    for i in range(sub.shape[0]):
        total = 0.0
        sd = sigma[i]
        ratio = sd / step
        if ratio >= FOURIER_RATIO:
            damping = math.exp(-2.0 * math.pi**2 * ratio * ratio)  # q: term m is damped by q^(m^2)
            terms = 1
            while damping ** ((terms + 1) ** 2) > FOURIER_TAIL:
                terms += 1
            for m in range(sub.shape[1]):
                steps = sub[i, m] / step
                t = 2.0 * math.pi * (steps - math.floor(steps))  # the phase within a step, as accurate as v
                sine, before, twice_cos = math.sin(t), 0.0, 2.0 * math.cos(t)
                series, sign = 0.0, -1.0
                for order in range(1, terms + 1):
                    series += sign * damping ** (order * order) * sine / order
                    sine, before = twice_cos * sine - before, sine
                    sign = -sign
                total += step / math.pi * series
            out[i] = total / sub.shape[1]
            continue
        for m in range(sub.shape[1]):
            v = sub[i, m]
            if sd <= 0:
                total += np.rint(v / step) * step - v
                continue
            lo = int(math.floor((v - 6.0 * sd) / step))
            hi = int(math.ceil((v + 6.0 * sd) / step))
            below = 0.5 * math.erfc(-((lo - 0.5) * step - v) / sd / root2)
            mass, first = 0.0, 0.0
            for k in range(lo, hi + 1):
                upper = 0.5 * math.erfc(-((k + 0.5) * step - v) / sd / root2)
                prob, below = upper - below, upper
                mass += prob
                first += prob * k * step
            total += (first / mass if mass > 0 else v) - v
        out[i] = total / sub.shape[1]
    return out


@njit(cache=True, nogil=True)
def _stored_mean(sub: np.ndarray, sigma_d: np.ndarray, step_d: float, focal_baseline: float, step_mm: float,
                 drift_mm: float) -> np.ndarray:  # pragma: no cover (compiled)
    """Per bin: the mean over its sample depths ``sub`` of E[stored] - (z + drift) (``stored_depth_bias``),
    the disparity levels within 6 sigma_d (the non-positive ones, invalid pixels, left out)."""
    root2 = math.sqrt(2.0)
    out = np.empty(sub.shape[0])
    for i in range(sub.shape[0]):
        total = 0.0
        sd = sigma_d[i]
        for m in range(sub.shape[1]):
            z0 = sub[i, m]
            d0 = focal_baseline / z0
            lo = max(1, int(math.floor((d0 - 6.0 * sd) / step_d)))
            hi = max(lo, int(math.ceil((d0 + 6.0 * sd) / step_d)))
            mass, first = 0.0, 0.0
            below = 0.5 * math.erfc(-((lo - 0.5) * step_d - d0) / sd / root2) if sd > 0 else 0.0
            for k in range(lo, hi + 1):
                if sd > 0:
                    upper = 0.5 * math.erfc(-((k + 0.5) * step_d - d0) / sd / root2)
                    prob, below = upper - below, upper
                else:
                    prob = 1.0 if abs(k * step_d - d0) <= 0.5 * step_d else 0.0
                value = focal_baseline / (k * step_d) + drift_mm
                if step_mm > 0:
                    value = np.rint(value / step_mm) * step_mm
                mass += prob
                first += prob * value
            total += (first / mass if mass > 0 else z0 + drift_mm) - (z0 + drift_mm)
        out[i] = total / sub.shape[1]
    return out
