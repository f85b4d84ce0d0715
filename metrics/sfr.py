"""Edge-based spatial frequency response (e-SFR) of a slanted edge, ISO 12233:2023.

Follows the e-SFR method of ISO 12233:2023 (pp. 11-13, Thesis 2024, 5.1.2) as
implemented by sfrmat5 (P. D. Burns, its reference implementation), in the steps
of Thesis 2024, 5.1.2; "sfrmat5 step N" refers to the step numbers in sfrmat5's source:

3-5. per-row derivative [-0.5, +0.5] of the (dark-to-bright) edge, windowed
     centroid, polynomial fit of edge position against row (order 5; order 1 when
     too few rows), re-windowing around the fitted edge and refit; rows limited to
     an integer number of phase cycles using the linear fit;
6.   projection of every pixel along the fitted edge into bins of 1/oversampling
     px of horizontal distance (cos(angle)/oversampling px along the normal),
     empty bins filled by interpolation;
7-8. LSF = [0.5, 0, -0.5] derivative of the ESF, centred on its peak, Tukey
     window (alpha = 1) over the full length;
9-10. |DFT| normalised to DC and multiplied by the derivative correction
     (pi k/N)/sin(pi k/N) (capped at 10);
11.  frequency axis in cycles/pixel normal to the edge (sampling corrected by the
     cosine of the edge angle); SFR50 / SFR10 by first crossing with linear
     interpolation.

Conventions: images are 2-D arrays indexed [row, column]; distances in pixels;
frequencies in cycles/pixel (cy/px). A "vertical" edge runs top to bottom of its
ROI; a "horizontal" one is analysed on the transposed ROI. The edge angle is
measured from that pixel axis, positive when the edge position grows with the
row (vertical) or column (horizontal) index.

Binning correction (labctl's addition to sfrmat5): averaging the projected
samples in bins of width 1/oversampling px smooths the ESF by that box, which
lowers the SFR by sinc(f cos(angle)/oversampling) -- 2.5 % at Nyquist with 4x
binning. ``edge_sfr`` divides it out by default (``bin_correction=True``);
``bin_correction=False`` reproduces sfrmat5, which does not correct it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from metrics.uncertainty import delete_a_group_jackknife

# sfrmat5: contrast test on the outer 5 columns; warning below 20 %.
_BAND = 5
_LOW_CONTRAST = 0.2
# sfrmat5: edge-location window is 0.95 * Tukey + 0.05 "to make edge finding stable".
_WINDOW_FLOOR = 0.05
# Rows needed per polynomial coefficient before the full-order fit is trusted.
_ROWS_PER_COEFFICIENT = 5
_MAX_FIT_ORDER = 5
# sfrmat5 fir2fix: derivative correction limited to 10.
_DERIVATIVE_CORRECTION_CAP = 10.0
# Edge angles (deg) that ISO 12233 slanted-edge analysis handles poorly.
_NEAR_ZERO_DEG = 2.0
_NEAR_45_DEG = 40.0
# docs/metrics.md, "Sharpness over distance": a run of >= 4 zero derivatives at an ESF end means clipping.
_CLIP_RUN = 4
# sfrmat5 clipping(): warn when more than 0.5 % of the ROI is at a sensor limit.
_CLIP_FRACTION = 0.005
_MIN_ROI = 10
_NYQUIST = 0.5

# ROI finder (find_edge_rois).
_ISO_MIN_ACROSS = 100
_ISO_MAX_ACROSS = 400
_SMOOTH_SIGMA = 1.5
_STRONG_GRADIENT = 0.3  # edge core, fraction of the strongest gradient
_ANY_GRADIENT = 0.1  # anything that must stay out of an ROI
_MIN_EDGE_LENGTH = 20
_MAX_LINE_RMS = 2.0
_END_TRIM = 0.1  # fraction of the edge length dropped at each end (corners)
_CLEARANCE = 8  # px of flat field kept on each side of the edge in every row
_OBSTACLE_MARGIN = 3


@dataclass(frozen=True, eq=False)
class SFRResult:
    """Result of :func:`edge_sfr`.

    frequency: cy/px normal to the edge, 0 ... 1; sfr: e-SFR at those frequencies
    (1 at DC); sfr10 / sfr50: first frequencies (cy/px) where the SFR falls below
    0.1 / 0.5, NaN if it never does; sfr_area: area under the SFR over 0 ... 1 cy/px
    (trapezoid rule on the samples, so it does not depend on the ROI length);
    angle_deg: edge angle from the pixel axis;
    orientation: "vertical" or "horizontal"; esf: supersampled edge profile in the
    image's units (1/oversampling px horizontal bins); lsf: its derivative, made
    positive (dark-to-bright), centred, before windowing; clipped: docs/metrics.md, "Sharpness over distance"
    criterion met; warnings: human-readable reasons to distrust the result.
    """

    frequency: np.ndarray
    sfr: np.ndarray
    sfr10: float
    sfr50: float
    sfr_area: float
    angle_deg: float
    orientation: str
    esf: np.ndarray
    lsf: np.ndarray
    clipped: bool
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class EdgeROI:
    """Region of interest around one slanted edge: columns x ... x+w-1, rows y ... y+h-1."""

    x: int
    y: int
    w: int
    h: int
    orientation: str
    warnings: tuple[str, ...] = ()

    def crop(self, image: np.ndarray) -> np.ndarray:
        """The ROI's pixels of ``image``.

        Examples
        --------
        >>> EdgeROI(x=1, y=2, w=3, h=2, orientation="vertical").crop(np.arange(30).reshape(5, 6)).tolist()
        [[13, 14, 15], [19, 20, 21]]
        """
        return _crop(np.asarray(image), (self.x, self.y, self.w, self.h))


# ----------------------------------------------------------------------------- e-SFR


def edge_sfr(
    image: np.ndarray,
    *,
    fit_order: int = 5,
    oversampling: int = 4,
    sensor_max: float | None = None,
    bin_correction: bool = True,
) -> SFRResult:
    """e-SFR of one ROI containing one slanted edge (ISO 12233:2023 e-SFR; sfrmat5).

    The edge must cross the ROI from one side to the opposite one, either
    near-vertical or near-horizontal, dark-to-bright or bright-to-dark.
    ``fit_order`` is the polynomial order of the edge fit (1...5; 5 as in sfrmat5,
    1 used instead when the ROI has fewer than 5 rows per coefficient);
    ``oversampling`` the number of ESF bins per pixel (4 in ISO 12233);
    ``sensor_max`` the sensor's upper limit (e.g. 4095) for the clipping check.
    ``bin_correction`` divides the SFR by the response of the ESF binning,
    sinc(f cos(angle) / oversampling) (labctl's addition, on by default: without
    it a sharp edge's SFR50 reads 1 % low at sigma = 0.4 px; False reproduces
    sfrmat5 exactly).
    Raises ValueError when the ROI is not 2-D, too small, not finite, or holds no
    usable edge.

    Examples
    --------
    An edge slanted by 5 deg, blurred by a Gaussian of sigma = 1 px across it: its SFR is
    exp(-2 pi^2 sigma^2 f^2), which falls to 0.5 at f = 0.187 cy/px and to 0.1 at 0.342 cy/px.

    >>> from scipy.special import ndtr
    >>> v, u = np.mgrid[0:60, 0:40].astype(float)
    >>> angle = np.radians(5.0)
    >>> result = edge_sfr(ndtr((u - 20.0 - (v - 29.5) * np.tan(angle)) * np.cos(angle)))
    >>> round(result.angle_deg, 1), result.orientation, round(result.sfr50, 2), round(result.sfr10, 2)
    (5.0, 'vertical', 0.19, 0.34)
    """
    if not 1 <= fit_order <= _MAX_FIT_ORDER:
        raise ValueError(f"fit_order must be 1...{_MAX_FIT_ORDER}, got {fit_order}")
    if oversampling < 1:
        raise ValueError(f"oversampling must be >= 1, got {oversampling}")
    roi = _as_image(image, "ROI")
    if min(roi.shape) < _MIN_ROI:
        raise ValueError(f"ROI too small: {roi.shape[0]}x{roi.shape[1]} px, need at least {_MIN_ROI}x{_MIN_ROI}")
    if not np.all(np.isfinite(roi)):
        raise ValueError(f"ROI contains {np.count_nonzero(~np.isfinite(roi))} non-finite pixels")

    a, orientation = _make_vertical(roi)
    sign, contrast = _polarity(a)
    warnings: list[str] = []
    if contrast < _LOW_CONTRAST:
        warnings.append(f"low edge contrast {contrast:.0%} (< {_LOW_CONTRAST:.0%}): SFR error may be high")

    nlin = a.shape[0]
    order = fit_order
    if nlin < _ROWS_PER_COEFFICIENT * (fit_order + 1):
        order = 1
        if fit_order > 1:
            warnings.append(
                f"too few rows along the edge ({nlin} < {_ROWS_PER_COEFFICIENT * (fit_order + 1)}): "
                f"linear edge fit used instead of order {fit_order}"
            )
    edge, slope = _locate_edge(a, sign, order)
    angle = float(np.degrees(np.arctan(slope)))
    warnings += _angle_warnings(angle)

    rows = _phase_rows(nlin, slope)
    esf, filled = _project(a[:rows], edge, oversampling)
    if not filled.all():
        warnings.append(
            f"{np.count_nonzero(~filled)} empty ESF bins filled by interpolation (edge angle or too few rows)"
        )
    lsf = _center_on_peak(_esf_derivative(esf, sign))
    cos_angle = float(np.cos(np.arctan(slope)))
    frequency, sfr = _dft_sfr(lsf, oversampling, cos_angle)
    if bin_correction:
        sfr = sfr / np.sinc(frequency * cos_angle / oversampling)

    clipped, clip_warnings = _clipping(roi, esf[filled], sensor_max)
    warnings += clip_warnings
    sfr10 = _first_crossing(frequency, sfr, 0.1)
    if sfr10 > _NYQUIST:
        warnings.append(f"SFR10 {sfr10:.3f} cy/px is above Nyquist ({_NYQUIST} cy/px): aliasing may affect it")
    return SFRResult(
        frequency=frequency,
        sfr=sfr,
        sfr10=sfr10,
        sfr50=_first_crossing(frequency, sfr, 0.5),
        sfr_area=_sfr_area(frequency, sfr),
        angle_deg=angle,
        orientation=orientation,
        esf=esf,
        lsf=lsf,
        clipped=clipped,
        warnings=tuple(warnings),
    )


def _make_vertical(a: np.ndarray) -> tuple[np.ndarray, str]:
    """sfrmat5 rotatev2: a horizontal edge changes the mean more from top to bottom
    than from left to right; such an ROI is transposed so the edge runs along rows."""
    top_bottom = abs(a[:_BAND].mean() - a[-_BAND:].mean())
    left_right = abs(a[:, :_BAND].mean() - a[:, -_BAND:].mean())
    if top_bottom > left_right:
        return a.T, "horizontal"
    return a, "vertical"


def _polarity(a: np.ndarray) -> tuple[float, float]:
    """Sign that makes the edge dark-to-bright, and the Michelson contrast of the
    outer column bands (sfrmat5: "we need a positive edge" and its 20 % contrast test)."""
    left = a[:, :_BAND].mean()
    right = a[:, -_BAND:].mean()
    if left == right:
        raise ValueError("no edge found: both sides of the ROI have the same mean level")
    total = abs(left) + abs(right)
    return (1.0 if right > left else -1.0), float(abs(right - left) / total)


def _row_derivative(a: np.ndarray, sign: float) -> np.ndarray:
    """[-0.5, +0.5] derivative along each row; sample j lies at column j + 0.5. As in
    sfrmat5 deriv1 the row length is kept and both end values are replaced by their
    neighbours (the first difference and the undefined last one)."""
    d = np.empty_like(a)
    d[:, :-1] = sign * 0.5 * np.diff(a, axis=1)
    d[:, 0] = d[:, 1]
    d[:, -1] = d[:, -2]
    return d


def _hann(x: np.ndarray, center: np.ndarray | float, half_width: np.ndarray | float) -> np.ndarray:
    """Tukey window with alpha = 1 (a Hann window) centred at ``center`` that reaches
    zero ``half_width`` away (sfrmat5 tukey2, asymmetric placement)."""
    t = (x - center) / half_width
    return np.where(np.abs(t) < 1.0, 0.5 * (1.0 + np.cos(np.pi * t)), 0.0)


def _row_centroids(d: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Centroid of each row of the derivative ``d`` (sample j at column j + 0.5)
    under 0.95 x Hann + 0.05 centred at ``center`` and reaching zero at the farther
    ROI border (sfrmat5 step 4)."""
    x = np.arange(d.shape[1]) + 0.5
    half = np.maximum(center, d.shape[1] - 1 - center) + 0.5
    w = (1.0 - _WINDOW_FLOOR) * _hann(x[None, :], center[:, None], half[:, None]) + _WINDOW_FLOOR
    weighted = d * w
    total = weighted.sum(axis=1)
    bad = np.flatnonzero(total <= 0)
    if bad.size:
        raise ValueError(
            f"no edge found in {bad.size} of {d.shape[0]} rows (first: row {bad[0]}): "
            "the edge must cross the ROI from one side to the opposite one"
        )
    return weighted @ x / total


def _locate_edge(a: np.ndarray, sign: float, order: int) -> tuple[np.polynomial.Polynomial, float]:
    """Edge position x(row) as a polynomial of ``order`` and the slope dx/drow of the
    linear fit (sfrmat5 steps 3-5: derivative, windowed centroid, fit, re-window
    around the fitted edge, refit)."""
    nlin, npix = a.shape
    d = _row_derivative(a, sign)
    rows = np.arange(nlin, dtype=float)
    centroids = _row_centroids(d, np.full(nlin, (npix - 1) / 2))
    edge = np.polynomial.Polynomial.fit(rows, centroids, order)
    centroids = _row_centroids(d, np.clip(edge(rows), 0.0, npix - 1.0))
    if not np.all((centroids > 0) & (centroids < npix - 1)):
        raise ValueError("no edge found: edge positions fall outside the ROI")
    edge = np.polynomial.Polynomial.fit(rows, centroids, order)
    slope = np.polynomial.Polynomial.fit(rows, centroids, 1).convert().coef[1]
    return edge, float(slope)


def _angle_warnings(angle: float) -> list[str]:
    if abs(angle) < _NEAR_ZERO_DEG:
        return [f"edge angle {angle:.2f} deg is near 0 deg: phase sampling is coarse"]
    if abs(angle) > _NEAR_45_DEG:
        return [f"edge angle {angle:.2f} deg is near 45 deg: projection bins fill unevenly"]
    return []


def _phase_rows(nlin: int, slope: float) -> int:
    """Rows kept so that the edge shifts by a whole number of pixels (ISO 12233
    integer number of phase cycles; sfrmat5 uses the linear fit for this)."""
    cycles = np.floor(nlin * abs(slope))
    if cycles < 1:
        raise ValueError(
            f"edge angle too close to 0 deg: the edge shifts by {nlin * abs(slope):.2f} px over "
            f"{nlin} rows, at least 1 px (one phase cycle) is needed"
        )
    return min(nlin, int(round(cycles / abs(slope))))


def _project(a: np.ndarray, edge: np.polynomial.Polynomial, oversampling: int) -> tuple[np.ndarray, np.ndarray]:
    """Supersampled ESF (sfrmat5 step 6, project2): every pixel is binned, in bins of
    1/oversampling px, by its column minus the edge's shift since row 0, so the bin
    grid is anchored at the edge in row 0; oversampling x (ROI width) bins are kept,
    starting half the edge's total shift before column 0, i.e. the ROI width as seen
    from the middle row (sfrmat5 takes the shift from the polynomial's linear
    coefficient, the slope at row 0, which a 5th-order fit can make meaningless).
    Empty bins are interpolated linearly from their neighbours.
    Returns the ESF and the mask of bins that received pixels."""
    nlin, npix = a.shape
    shift = edge(np.arange(nlin, dtype=float)) - edge(0.0)
    distance = np.arange(npix)[None, :] - shift[:, None]
    first = -int(round(oversampling * shift[-1] / 2))
    bins = np.ceil(distance * oversampling).astype(np.int64).ravel() - first
    n = oversampling * npix
    inside = (bins >= 0) & (bins < n)
    counts = np.bincount(bins[inside], minlength=n)
    sums = np.bincount(bins[inside], weights=a.ravel()[inside], minlength=n)
    filled = counts > 0
    index = np.arange(n)
    return np.interp(index, index[filled], sums[filled] / counts[filled]), filled


def _esf_derivative(esf: np.ndarray, sign: float) -> np.ndarray:
    """LSF by the [0.5, 0, -0.5] central difference, end values repeated, made
    positive for a bright-to-dark edge (sfrmat5 step 7)."""
    lsf = np.empty_like(esf)
    lsf[1:-1] = sign * 0.5 * (esf[2:] - esf[:-2])
    lsf[0], lsf[-1] = lsf[1], lsf[-2]
    return lsf


def _center_on_peak(lsf: np.ndarray) -> np.ndarray:
    """Shift so that the LSF maximum sits at index n // 2, zero fill (sfrmat5 cent)."""
    n = lsf.size
    peak = np.flatnonzero(lsf == lsf.max()).mean()
    shift = n // 2 - int(round(peak))
    out = np.zeros_like(lsf)
    if shift >= 0:
        out[shift:] = lsf[: n - shift]
    else:
        out[:shift] = lsf[-shift:]
    return out


def _dft_sfr(lsf: np.ndarray, oversampling: int, cos_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Windowed LSF -> |DFT| / DC x derivative correction, on a frequency axis in
    cy/px normal to the edge, 0 ... 1 cy/px (sfrmat5 steps 8-11)."""
    n = lsf.size
    center = n // 2
    windowed = lsf * _hann(np.arange(n), center, max(center, n - 1 - center))
    spectrum = np.abs(np.fft.rfft(windowed))
    if spectrum[0] <= 0:
        raise ValueError("no edge found: the line spread function has no positive area")
    k = np.arange(spectrum.size)
    frequency = k * oversampling / (n * cos_angle)
    keep = frequency <= 1.0
    return frequency[keep], spectrum[keep] / spectrum[0] * _derivative_correction(k[keep], n)


def _derivative_correction(k: np.ndarray, n: int) -> np.ndarray:
    """Inverse response of the [0.5, 0, -0.5] difference at DFT index k of length n:
    (pi k/N)/sin(pi k/N) with N = n/2, capped at 10 (sfrmat5 step 10, fir2fix, which
    evaluates it one index higher, pi (k+1)/(N+2))."""
    phase = 2.0 * np.pi * k / n
    with np.errstate(divide="ignore", invalid="ignore"):
        correction = np.where(k == 0, 1.0, phase / np.sin(phase))
    valid = (correction > 0) & (correction < _DERIVATIVE_CORRECTION_CAP)
    return np.where(valid, correction, _DERIVATIVE_CORRECTION_CAP)


def _first_crossing(frequency: np.ndarray, sfr: np.ndarray, level: float) -> float:
    """First frequency where the SFR drops below ``level``, linearly interpolated
    between the samples around it (sfrmat5 findfreq); NaN if it never does."""
    below = np.flatnonzero(sfr < level)
    if below.size == 0 or below[0] == 0:
        return float("nan")
    i = below[0]
    fraction = (sfr[i - 1] - level) / (sfr[i - 1] - sfr[i])
    return float(frequency[i - 1] + fraction * (frequency[i] - frequency[i - 1]))


def _sfr_area(frequency: np.ndarray, sfr: np.ndarray) -> float:
    """Area under the SFR over 0 ... 1 cy/px (docs/metrics.md, "Sharpness over distance", Thesis 2024, 5.1.2): the sum
    of the samples times the frequency step, the two end samples weighted 1/2
    (trapezoid rule). With full weights the DC sample alone would add step/2, which
    depends on the ROI length (1-3 % between 100 and 400 px wide ROIs)."""
    step = frequency[1] - frequency[0]
    return float(step * (np.sum(sfr) - (sfr[0] + sfr[-1]) / 2))


def _clipping(roi: np.ndarray, esf: np.ndarray, sensor_max: float | None) -> tuple[bool, list[str]]:
    """docs/metrics.md, "Sharpness over distance": a run of >= 4 zero derivatives (steps below 1e-9 of the ESF
    range, i.e. zero up to rounding) at either end of the ESF (its measured bins),
    or more than 0.5 % of the ROI at a sensor limit (0, ``sensor_max``; threshold
    of sfrmat5 clipping()). A noise-free rendering has perfectly flat plateaus and
    therefore also meets the first criterion."""
    warnings = []
    flat = np.abs(np.diff(esf)) <= 1e-9 * max(np.ptp(esf), np.finfo(float).tiny)
    for end, run in (("start", flat[:_CLIP_RUN]), ("end", flat[-_CLIP_RUN:])):
        if run.size == _CLIP_RUN and run.all():
            warnings.append(f"clipping: >= {_CLIP_RUN} zero ESF derivatives at the {end} of the ESF")
    limits = {"0": roi <= 0}
    if sensor_max is not None:
        limits[f"sensor maximum {sensor_max:g}"] = roi >= sensor_max
    for name, at_limit in limits.items():
        fraction = np.count_nonzero(at_limit) / roi.size
        if fraction > _CLIP_FRACTION:
            warnings.append(f"clipping: {fraction:.1%} of the ROI at the sensor limit {name}")
    return bool(warnings), warnings


# ----------------------------------------------------------------------------- ROIs


def find_edge_rois(
    image: np.ndarray,
    *,
    min_angle_deg: float = _NEAR_ZERO_DEG,
    max_angle_deg: float = 20.0,
) -> list[EdgeROI]:
    """Find ROIs around the slanted vertical and horizontal edges of a chart image;
    ISO 12233:2023 (p. 12, Thesis 2024, 5.1.2) asks for 100-400 px across the edge.

    Straight edges are connected runs of strong gradient (>= 30 % of the strongest,
    after a 3x3 median and a Gaussian of 1.5 px) whose fitted line is slanted by
    ``min_angle_deg``...``max_angle_deg`` from the pixel axis; axis-aligned borders
    (e.g. the sheet against a dark background) are thus not taken as edges, but
    they, other edges and corners are kept out of every ROI. Each ROI spans the
    middle 80 % of its edge and is as wide as the free space allows, up to 400 px;
    narrower than 100 px gives a warning. An edge with too little free space for
    any ROI is skipped. Returns vertical edges first, then horizontal ones, each
    longest first; an empty list when none is found.

    Examples
    --------
    One edge slanted by 5 deg through the middle of a 120 x 120 image.

    >>> from scipy.special import ndtr
    >>> v, u = np.mgrid[0:120, 0:120].astype(float)
    >>> rois = find_edge_rois(0.1 + 0.8 * ndtr(u - 60.0 - (v - 59.5) * np.tan(np.radians(5.0))))
    >>> len(rois), rois[0].orientation, rois[0].x < 55 and rois[0].x + rois[0].w > 65
    (1, 'vertical', True)
    """
    vertical, horizontal = _edge_candidates(_as_image(image, "image"), min_angle_deg, max_angle_deg)
    rois = [EdgeROI(c.x, c.y, c.w, c.h, "vertical", c.warnings) for c in vertical]
    # horizontal candidates were found on the transposed image
    rois += [EdgeROI(c.y, c.x, c.h, c.w, "horizontal", c.warnings) for c in horizontal]
    return rois


@dataclass(frozen=True)
class _Candidate:
    """ROI (x, y, w, h) around a near-vertical edge of ``length`` rows."""

    x: int
    y: int
    w: int
    h: int
    length: int
    spans_image: bool
    unobstructed: bool
    warnings: tuple[str, ...]


def _edge_candidates(
    a: np.ndarray, min_angle: float, max_angle: float
) -> tuple[list[_Candidate], list[_Candidate]]:
    """Candidates for vertical edges, and for horizontal ones in transposed coordinates."""
    gx, gy, strong, anything = _gradient_maps(a)
    vertical = _vertical_candidates(gx, gy, strong, anything, min_angle, max_angle)
    horizontal = _vertical_candidates(gy.T, gx.T, strong.T, anything.T, min_angle, max_angle)
    return vertical, horizontal


def _gradient_maps(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sobel gradients of the despeckled, smoothed image and masks of strong edge
    cores and of any noticeable edge."""
    smooth = cv2.GaussianBlur(cv2.medianBlur(a.astype(np.float32), 3), (0, 0), _SMOOTH_SIGMA).astype(float)
    gx = cv2.Sobel(smooth, cv2.CV_64F, 1, 0, ksize=3)
    gy = cv2.Sobel(smooth, cv2.CV_64F, 0, 1, ksize=3)
    magnitude = np.hypot(gx, gy)
    peak = magnitude.max()
    if peak <= 0:
        return gx, gy, np.zeros(a.shape, bool), np.zeros(a.shape, bool)
    return gx, gy, magnitude >= _STRONG_GRADIENT * peak, magnitude >= _ANY_GRADIENT * peak


def _vertical_candidates(
    gx: np.ndarray, gy: np.ndarray, strong: np.ndarray, anything: np.ndarray, min_angle: float, max_angle: float
) -> list[_Candidate]:
    """ROIs around near-vertical edges: connected strong-gradient pixels whose
    gradient points mostly along x, fitted by a line x(row), longest first."""
    magnitude = np.hypot(gx, gy)
    mask = (strong & (np.abs(gx) >= np.abs(gy))).astype(np.uint8)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    obstacles = np.nonzero(anything)
    candidates = []
    for label in np.flatnonzero(stats[1:, cv2.CC_STAT_HEIGHT] >= _MIN_EDGE_LENGTH) + 1:
        rows, cols = np.nonzero(labels == label)
        line = _fit_line(rows, cols, magnitude[rows, cols])
        if line is not None and min_angle <= np.degrees(np.arctan(abs(line[1]))) <= max_angle:
            candidate = _roi_around(int(rows.min()), int(rows.max()), line, obstacles, anything.shape)
            if candidate is not None:
                candidates.append(candidate)
    return sorted(candidates, key=lambda c: -c.length)


def _fit_line(rows: np.ndarray, cols: np.ndarray, weight: np.ndarray) -> tuple[float, float, float] | None:
    """Least-squares line x = intercept + slope * row through the gradient-weighted
    centre of each row, and the half-width of the pixel band around it; None when
    the band is not straight."""
    offset = rows.min()
    total = np.bincount(rows - offset, weights=weight)
    center = np.bincount(rows - offset, weights=weight * cols)
    present = total > 0
    y = np.flatnonzero(present) + offset
    x = center[present] / total[present]
    slope, intercept = np.polyfit(y, x, 1)
    if np.sqrt(np.mean((x - (intercept + slope * y)) ** 2)) > _MAX_LINE_RMS:
        return None
    band = np.abs(cols - (intercept + slope * rows)).max()
    return float(intercept), float(slope), float(band)


def _roi_around(
    first: int,
    last: int,
    line: tuple[float, float, float],
    obstacles: tuple[np.ndarray, np.ndarray],
    shape: tuple[int, int],
) -> _Candidate | None:
    """Axis-aligned ROI over the middle 80 % of the edge rows first...last, as wide
    as possible without other edges (``obstacles``: row and column indices of
    every noticeable gradient) or the image border, at most 400 px."""
    intercept, slope, band = line
    length = last - first + 1
    trim = int(np.ceil(_END_TRIM * length))
    r0, r1 = first + trim, last - trim
    middle = (r0 + r1) / 2
    xc = intercept + slope * middle
    rows, cols = obstacles
    others = np.abs(cols - (intercept + slope * rows)) > 2 * band + _OBSTACLE_MARGIN
    in_rows = others & (rows >= r0) & (rows <= r1)
    free = np.abs(cols[in_rows] - xc).min() - _OBSTACLE_MARGIN if in_rows.any() else np.inf
    half = min(free, _ISO_MAX_ACROSS / 2, xc + 0.5, shape[1] - 0.5 - xc)
    # The edge must stay _CLEARANCE px inside the ROI in every row.
    max_rows = int(2 * (half - _CLEARANCE) / abs(slope)) if half > _CLEARANCE else 0
    if max_rows < 1 / abs(slope):
        return None
    if r1 - r0 + 1 > max_rows:
        r0 = int(round(middle - max_rows / 2))
        r1 = r0 + max_rows - 1
    x0, x1 = int(np.ceil(xc - half)), int(np.floor(xc + half))
    warnings = ()
    if x1 - x0 + 1 < _ISO_MIN_ACROSS:
        warnings = (f"ROI only {x1 - x0 + 1} px across the edge (ISO 12233:2023: 100-400 px)",)
    return _Candidate(
        x=x0,
        y=r0,
        w=x1 - x0 + 1,
        h=r1 - r0 + 1,
        length=length,
        spans_image=first == 0 and last == shape[0] - 1,
        unobstructed=not others.any(),
        warnings=warnings,
    )


# ----------------------------------------------------------------------------- helpers


def normalize_by_white(image: np.ndarray, white: np.ndarray) -> np.ndarray:
    """Pixel-wise division by a white-reference image (white sheet over the chart),
    Thesis 2024, 5.1.2: removes the illumination fall-off of active cameras so
    the ESF only changes at the edge. Pixels whose reference is not positive and
    finite become NaN. Result: reflectance relative to the white sheet.

    Examples
    --------
    >>> normalize_by_white(np.array([[50.0, 100.0, 7.0]]), np.array([[100.0, 200.0, 0.0]])).tolist()
    [[0.5, 0.5, nan]]
    """
    a = _as_image(image, "image")
    w = _as_image(white, "white reference")
    if a.shape != w.shape:
        raise ValueError(f"image {a.shape} and white reference {w.shape} differ in shape")
    valid = np.isfinite(w) & (w > 0)
    out = np.full(a.shape, np.nan)
    np.divide(a, w, out=out, where=valid)
    return out


def sfr10_jackknife(chart_replicates: np.ndarray, white_replicates: np.ndarray) -> float:
    """Type A standard uncertainty (GUM 4.2) of the SFR10 of one edge ROI of a white-normalized stack mean: the
    delete-a-group jackknife (``metrics.uncertainty.delete_a_group_jackknife``; Efron & Tibshirani 1993, 11.2)
    over G groups of frames, from the (G, h, w) ROI of the chart's and of the white reference's stack mean each
    without group g (``metrics.stack.leave_group_out_means``), replicate g the :func:`edge_sfr` of their
    :func:`normalize_by_white`. A replicate without an SFR10 (no edge found, the SFR not falling to 10 %) is left
    out; NaN where fewer than two remain.

    Examples
    --------
    An edge slanted by 5 deg, blurred by a Gaussian of sigma = 1.0, 1.1 and 1.2 px in three replicates: SFR10 =
    sqrt(2 ln 10) / (2 pi sigma) = 0.342, 0.311, 0.285 cy/px, whose jackknife sqrt(2 / 3 sum (f - mean f)^2) is
    0.033 cy/px.

    >>> from scipy.special import erf
    >>> v, u = np.mgrid[0:60, 0:40].astype(float)
    >>> across = (u - 20 - (v - 30) * np.tan(np.radians(5))) / np.sqrt(2)
    >>> charts = np.array([0.2 + 0.3 * (1 + erf(across / sigma)) for sigma in (1.0, 1.1, 1.2)])
    >>> round(sfr10_jackknife(charts, np.ones_like(charts)), 3)
    0.033
    """
    values = []
    for chart, white in zip(chart_replicates, white_replicates, strict=True):
        try:
            values.append(edge_sfr(normalize_by_white(chart, white)).sfr10)
        except ValueError:
            values.append(np.nan)
    return delete_a_group_jackknife(np.array(values)[:, None])[0]


def analyze_image(
    image: np.ndarray, roi: tuple[int, int, int, int] | None = None, *, sensor_max: float | None = None,
    bin_correction: bool = True,
) -> SFRResult:
    """e-SFR of an image (``labctl analyze sfr IMAGE [--roi X,Y,W,H]``).

    ``roi`` = (x, y, w, h) in pixels. Without it, the whole image is analysed when
    it holds a single edge running through it and nothing else, otherwise the first
    ROI of :func:`find_edge_rois`. Raises ValueError when no edge is found.

    Examples
    --------
    An image holding one edge slanted by 5 deg, blurred by sigma = 1 px (SFR50 = 0.187 cy/px, as in
    :func:`edge_sfr`), is analysed whole.

    >>> from scipy.special import ndtr
    >>> v, u = np.mgrid[0:120, 0:120].astype(float)
    >>> angle = np.radians(5.0)
    >>> result = analyze_image(0.1 + 0.8 * ndtr((u - 60.0 - (v - 59.5) * np.tan(angle)) * np.cos(angle)))
    >>> round(result.angle_deg, 1), round(result.sfr50, 2)
    (5.0, 0.19)
    """
    a = _as_image(image, "image")
    options = {"sensor_max": sensor_max, "bin_correction": bin_correction}
    if roi is not None:
        return edge_sfr(_crop(a, roi), **options)
    if _is_single_edge(a):
        return edge_sfr(a, **options)
    rois = find_edge_rois(a)
    if not rois:
        raise ValueError("no slanted edge found in the image; give the ROI explicitly")
    return edge_sfr(rois[0].crop(a), **options)


def _is_single_edge(a: np.ndarray) -> bool:
    """True when one slanted edge crosses the whole image and no other edge exists."""
    vertical, horizontal = _edge_candidates(a, _NEAR_ZERO_DEG, _NEAR_45_DEG)
    candidates = vertical + horizontal
    return len(candidates) == 1 and candidates[0].spans_image and candidates[0].unobstructed


def load_image(path: str | Path) -> np.ndarray:
    """Load a png/tif/bmp (OpenCV, unchanged bit depth) or npy image as float64;
    of a colour image, the file's first channel (red; OpenCV stores BGR).

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     np.save(Path(folder) / "image.npy", np.array([[1, 2], [3, 4]], dtype=np.uint16))
    ...     image = load_image(Path(folder) / "image.npy")
    >>> image.dtype, image.tolist()
    (dtype('float64'), [[1.0, 2.0], [3.0, 4.0]])
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        a = np.load(path, allow_pickle=False)
        if a.ndim == 3:
            a = a[..., 0]
    elif suffix in {".png", ".tif", ".tiff", ".bmp"}:
        a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if a is None:
            raise ValueError(f"cannot decode image file: {path}")
        if a.ndim == 3:
            a = a[..., 2]
    else:
        raise ValueError(f"unsupported image type {suffix!r} ({path}); use png, tif, bmp or npy")
    return _as_image(a, str(path))


def _as_image(image: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(image, dtype=float)
    if a.ndim != 2:
        raise ValueError(f"{what} must be a 2-D array, got shape {a.shape}")
    return a


def _crop(a: np.ndarray, roi: tuple[int, int, int, int]) -> np.ndarray:
    x, y, w, h = (int(v) for v in roi)
    if w < 1 or h < 1 or x < 0 or y < 0 or x + w > a.shape[1] or y + h > a.shape[0]:
        raise ValueError(f"ROI x={x}, y={y}, w={w}, h={h} is not inside the {a.shape[1]}x{a.shape[0]} image")
    return a[y : y + h, x : x + w]
