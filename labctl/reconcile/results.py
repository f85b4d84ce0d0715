"""What reconcile decides, as typed records: the named effects with their evidence, the candidates' scores, the
goodness of fit, the corner comparison, the unexplained residual's characterization, the empirical corrections,
an ambiguity, a not-comparable run's needs, and ``reconcile.json`` itself (docs/reconcile.md).
``labctl.jsondoc.to_json`` turns them into JSON, keys in field order."""

from __future__ import annotations

from dataclasses import dataclass, field

from labctl.jsondoc import inline, optional

#: a parameter's value as a model file (TOML) holds it: a number, flag or name, or a list or table of them
ParameterValue = float | int | bool | str | list["ParameterValue"] | dict[str, "ParameterValue"]
#: an effect's parameters by name
Parameters = dict[str, ParameterValue]


@dataclass(kw_only=True)
class ExcludedStep:
    """A measured step left out of one residual family's comparison (``family`` ``"all"``: of every one), and
    why."""

    step: str
    family: str
    reason: str


@dataclass(kw_only=True)
class Correlation:
    """The correlation of two fitted parameters' estimates."""

    between: list[str]
    correlation: float


@dataclass(kw_only=True)
class Determination:
    """Whether the run determines an effect's fitted parameters; when not, the problems and the capture that would.
    ``interval_95`` and ``correlations`` are absent when no covariance could be computed (``correlations`` also
    for effects named from the checkerboard corners)."""

    well_determined: bool
    interval_95: dict[str, list[float]] | None = optional()
    correlations: list[Correlation] | None = optional()
    problems: list[str]
    capture: str | None


@dataclass(kw_only=True)
class Evidence:
    """Why an effect was named: its score against the runner-up, its parameters' standard errors and
    determination, and the gap it closed. ``family`` is ``"corners"`` for effects named from the checkerboard
    corners (whose gaps are given in px as well and which are not cross-validated by step: ``loso_gain`` None);
    the depth rounds give the intensity gap instead."""

    family: str | None = optional()
    delta_bic: float
    loso_gain: float | None
    runner_up: str | None
    runner_up_delta_bic: float | None
    stderr: dict[str, float]
    determination: Determination
    rss_before: float
    rss_after: float
    gap_before_mm: float
    gap_after_mm: float
    gap_before_px: float | None = optional()
    gap_after_px: float | None = optional()
    intensity_gap_before_pct: float | None = optional()
    intensity_gap_after_pct: float | None = optional()
    steps: int
    p_value: float | None = optional()  # against the null runs (labctl/reconcile/null.py), when there were any
    null_runs: int | None = optional()


@dataclass(kw_only=True)
class NamedEffect:
    """An effect reconcile named and added to the model (``named_effects`` of reconcile.json)."""

    name: str
    parameters: Parameters
    evidence: Evidence


@dataclass(kw_only=True)
class CandidateScore:
    """A candidate effect's score (dBIC over steps) in the first round."""

    name: str
    score: float


@dataclass(kw_only=True)
class EmpiricalCorrection:
    """An empirical correction added to the model for a residual no library effect explains."""

    name: str
    parameters: Parameters
    empirical: bool = True
    gap_before_mm: float
    gap_after_mm: float


@dataclass(kw_only=True)
class Ambiguity:
    """Two candidates the run cannot tell apart, and the capture that would separate them."""

    between: list[str]
    scores: list[float]
    separating_capture: str


@dataclass(kw_only=True)
class NotComparable:
    """Why a run could not be compared and the procedures that would give the comparison something to work with."""

    reason: str
    comparable_steps: list[str]
    procedures_needed: dict[str, str]
    not_compared: str


@dataclass(kw_only=True)
class CornerCandidate:
    """A corner candidate's score and fitted parameters in one round."""

    name: str
    score: float
    parameters: Parameters


@dataclass(kw_only=True)
class CornerRound:
    """One round of the corner comparison: the model compared, its gap and floor (mm), what was decided and, when
    candidates were fitted, their scores."""

    model_effects: list[str]
    gap: float | None
    gap_floor: float | None
    decision: str
    candidates: list[CornerCandidate] | None = optional()


@dataclass(kw_only=True)
class StepAboveFloor:
    """A step whose gap exceeds its noise floor in one residual family (rounded; None where not finite)."""

    step: str
    family: str
    gap: float | None
    floor: float | None
    ratio: float | None


@dataclass(kw_only=True)
class GoodnessSummary:
    """The goodness of fit of one model (labctl/reconcile/goodness.py): the depth gap (mm) and intensity gap (%)
    with their floors (rounded; None where not finite), the consistency with the noise per family and together,
    the step rule's factor, and the steps furthest above their floors (at most five)."""

    gap: float | None
    gap_floor: float | None
    intensity_gap: float | None
    intensity_gap_floor: float | None
    consistent_with_noise: bool
    depth_consistent: bool
    intensity_consistent: bool
    step_factor: float
    families: dict[str, FamilyGoodness]
    steps_above_floor: list[StepAboveFloor]
    null: NullJudgement | None = inline(None)  # set by the decision rule (json_document)


@dataclass(kw_only=True)
class FamilyGoodness:
    """One residual family of a goodness of fit (depth, intensity, noise, validity, correlation): the run's gap
    and its floor in the family's unit, whether it is consistent with the noise, and how many steps it compared."""

    gap: float | None
    floor: float | None
    unit: str
    consistent: bool
    steps: int


@dataclass(kw_only=True)
class NullJudgement:
    """A goodness of fit judged against the campaign's null replicas (labctl/reconcile/null.py): the combined
    empirical p-value, the K replicas used, and every statistic with its own p-value."""

    p_value: float
    null_runs: int
    statistics: dict[str, float]
    statistic_p_values: dict[str, float]


@dataclass(kw_only=True)
class RoundGoodness:
    """One depth round in ``goodness_of_fit``: the model compared, what was decided and, when the round's
    residual was compared with the noise, that goodness of fit (its keys in place)."""

    model_effects: list[str]
    decision: str
    goodness: GoodnessSummary | None = inline()
    candidate_p_value: float | None = optional()  # the round's best candidate against the null runs' best


@dataclass(kw_only=True)
class GoodnessOfFit:
    """``goodness_of_fit`` of reconcile.json: before any named effect, per round, with the named physical effects
    only and with the final model (None where the run has no depth comparison)."""

    before: GoodnessSummary | None
    rounds: list[RoundGoodness]
    after_physical: GoodnessSummary | None
    after: GoodnessSummary | None


@dataclass(kw_only=True)
class SignificanceRule:
    """The thresholds an effect passed to be named (labctl/reconcile/goodness.py, labctl/reconcile/workflow.py)."""

    material_fraction: float
    floor_fraction: float
    dbic_threshold: float


@dataclass(kw_only=True)
class CornerFamilyGoodness:
    """One corner family's gap and floor (rounded, in ``unit``) and its consistency with the noise; the image
    family also in px."""

    gap: float | None
    gap_floor: float | None
    unit: str
    consistent_with_noise: bool
    gap_px: float | None = optional()
    gap_floor_px: float | None = optional()


@dataclass(kw_only=True)
class CornerGoodnessSummary:
    """The goodness of fit of the checkerboard corners (labctl/reconcile/corners.py): per family, then both
    families together (mm in the board plane), and the steps furthest above their floors (at most five)."""

    corner_image: CornerFamilyGoodness
    corner_cloud: CornerFamilyGoodness
    gap: float | None
    gap_floor: float | None
    consistent_with_noise: bool
    steps_above_floor: list[StepAboveFloor]

    def families(self) -> dict[str, CornerFamilyGoodness]:
        """The families by name, in the document's order."""
        return {"corner_image": self.corner_image, "corner_cloud": self.corner_cloud}


@dataclass(kw_only=True)
class CornersSection:
    """``corners`` of reconcile.json: the checkerboard steps compared, the goodness before and after, the effects
    named from the corners, the rounds, the consistency with the noise and an ambiguity (None without one)."""

    steps: list[str]
    before: CornerGoodnessSummary
    after: CornerGoodnessSummary
    named_effects: list[str]
    rounds: list[CornerRound]
    consistent_with_noise: bool
    ambiguity: Ambiguity | None


@dataclass(kw_only=True)
class CurvePoint:
    """One group of an axis's curve: its centre (or category), the residual's weighted mean there, its bins."""

    x: float | str
    mean_mm: float
    n: int


@dataclass(kw_only=True)
class AxisSummary:
    """An axis the unexplained residual was tried against: its unit, the share of the residual's variance it
    carries (eta^2), the curve's peak to peak and, for the pixel axes, how alike the curve is near and far."""

    axis: str
    unit: str
    eta2: float
    effect_mm: float
    same_at_every_distance: float | None = optional()


@dataclass(kw_only=True)
class Confounded:
    """An axis the run cannot tell from the carrying one: their Spearman correlation over the compared bins."""

    axis: str
    spearman_rho: float


@dataclass(kw_only=True)
class StatisticsAxis:
    """An axis a statistics family's residual was tried against: its unit and the share of the residual's
    variance it carries (eta^2)."""

    axis: str
    unit: str
    eta2: float


@dataclass(kw_only=True)
class StatisticsCurvePoint:
    """One group of a statistics family's curve: its centre, the residual's weighted mean there (the family's
    unit: log ratio, or valid fraction), its bins."""

    x: float | str
    mean: float
    n: int


@dataclass(kw_only=True)
class DepartureAtEnds:
    """A statistics family's departure that changes sign along the carrying axis: the residual's weighted mean
    (the family's unit) at the first and the last group of the curve."""

    at_ends: list[float]


@dataclass(kw_only=True)
class ValidityDeparture:
    """The valid fraction's departure where it departs most: measured over predicted valid pixels, minus one
    (``relative_change``), and the residual's weighted mean there (``difference``)."""

    relative_change: float
    difference: float


@dataclass(kw_only=True)
class DepartureFactor:
    """The noise's or the correlation's departure where it departs most: the log ratio's weighted mean,
    exponentiated (a factor on the model's)."""

    factor: float


@dataclass(kw_only=True)
class FamilyDeparture:
    """How a statistics family (noise, validity, correlation) departs from the model
    (labctl/reconcile/characterize.py ``describe_statistics``): the axis carrying it and where along it, the
    departure (its keys in place: at the curve's ends where it changes sign; else the valid fraction's
    relative change and difference, or the noise's and correlation's factor), the axes tried, the carrying
    axis's curve, one sentence, and the family's gap and floor. A family with no compared bins has only its
    name, the sentence, gap and floor."""

    family: str
    carrying_axis: str | None
    where: str | None = optional()
    departure: DepartureAtEnds | ValidityDeparture | DepartureFactor | None = inline(None)
    axes: list[StatisticsAxis] | None = optional()
    curve: list[StatisticsCurvePoint] | None = optional()
    description: str
    gap: float | None = None
    floor: float | None = None


@dataclass(kw_only=True)
class Unexplained:
    """``unexplained`` of reconcile.json (labctl/reconcile/characterize.py): the axes by eta^2, the carrying axis
    (None when none carries the residual), the axes confounded with it and its curve (absent when no bin was
    compared), the mean residual map (mm, None where no bin), one sentence on what the residual follows, and
    what the user reads (set with the verdict)."""

    axes: list[AxisSummary]
    carrying_axis: str | None
    confounded_with: list[Confounded] | None = optional()
    curve: list[CurvePoint] | None = optional()
    spatial_map_mm: list[list[float | None]]
    description: str
    families: list[FamilyDeparture] | None = optional()  # the statistics families above their floors
    message: str | None = optional()


@dataclass(kw_only=True)
class ResidualFamily:
    """One residual family of reconcile.json's ``families`` (depth, intensity, noise, validity, correlation,
    corners): its gap before and after (the final model), its floor and unit, whether it is consistent with the
    noise, and how many steps it compared."""

    gap_before: float | None
    gap_after: float | None
    floor: float | None
    unit: str
    consistent: bool
    steps: int


@dataclass(kw_only=True)
class ValueRange:
    """The smallest, median and largest of a statistic over the null replicas (rounded; None when none is
    finite)."""

    min: float | None
    median: float | None
    max: float | None


@dataclass(kw_only=True)
class MinimumDetectable:
    """An effect's minimum detectable amplitude (labctl/reconcile/power.py): the amplitude parameter, the amplitude
    named with 90 % probability at the median point of the effect's grid of nonlinear parameters (None: none
    within reach), its smallest and largest over the grid points evaluated, the parameters at the median, and
    the competing candidate that reproduces most of the effect's change there (None when none competes; with
    no amplitude: the effect is not separable from it in this campaign)."""

    parameter: str
    amplitude: float | None
    grid_min: float | None
    grid_max: float | None
    grid_points: int
    at: Parameters
    rival: str | None = None


@dataclass(kw_only=True)
class CalibrationSection:
    """``null_calibration`` of reconcile.json: the decision rule. Fixed thresholds: the dBIC threshold and the
    floors' fractions. Null runs: the K replicas (seeds, seconds, workers, how many came from the cache), the
    p-value's formula, the null
    distributions of the residual statistics and of the candidates' dBIC, how later rounds are judged, and the
    minimum detectable amplitudes."""

    method: str
    null_runs: int
    alpha: float | None = optional()
    p_value: str | None = optional()
    seeds: list[int] | None = optional()
    seconds: float | None = optional()
    workers: int | None = optional()
    cached: int | None = optional()
    null_statistics: dict[str, ValueRange] | None = optional()
    null_best_delta_bic: ValueRange | None = optional()
    null_delta_bic: dict[str, ValueRange] | None = optional()
    later_rounds: str | None = optional()
    dbic_threshold: float | None = optional()
    material_fraction: float
    floor_fraction: float | None = optional()
    minimum_detectable: dict[str, MinimumDetectable] | None = optional()


@dataclass(kw_only=True)
class ReconcileDocument:
    """``reconcile.json`` (docs/reconcile.md): the verdict, named effects, candidates and gaps first; then the
    gap floor and consistency, per-round goodness of fit, significance rule, empirical corrections, notes and the
    calibration of the decisions (with null runs the minimum detectable amplitudes); the
    corner comparison, the unexplained residual's characterization, a not-comparable run's needs and an
    ambiguity only where they apply."""

    verdict: str
    named_effects: list[NamedEffect]
    candidates: list[CandidateScore]
    gap_before: float | None
    gap_after: float | None
    gap_unit: str = "mm"
    model_toml: str
    gap_floor: float | None
    consistent_with_noise: bool | None
    gap_after_physical: float | None
    intensity_gap_before: float | None
    intensity_gap_after: float | None
    intensity_gap_floor: float | None
    intensity_gap_unit: str = "%"
    goodness_of_fit: GoodnessOfFit
    significance_rule: SignificanceRule
    empirical_corrections: list[EmpiricalCorrection]
    notes: list[str]
    not_tested: dict[str, str] = field(default_factory=dict)  # effect -> why this run cannot test it
    calibration: str = "fixed thresholds"  # or "null runs" (labctl/reconcile/null.py)
    null_calibration: CalibrationSection | None = optional()
    minimum_detectable: dict[str, float | None] | None = optional()  # effect -> amplitude named with 90 % probability
    families: dict[str, ResidualFamily]
    excluded_steps: list[ExcludedStep]
    corners: CornersSection | None = optional()
    unexplained: Unexplained | None = optional()
    not_comparable: NotComparable | None = optional()
    ambiguity: Ambiguity | None = optional()
