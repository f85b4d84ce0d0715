"""What reconcile decides, as typed records: the named effects with their evidence, the candidates' scores, the
empirical corrections, an ambiguity, a not-comparable run's needs, and ``reconcile.json`` itself
(docs/reconcile.md). ``labctl.jsondoc.to_json`` turns them into JSON, keys in field order."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from labctl.jsondoc import optional

#: an effect's parameters as a model file holds them (numbers, flags, lists, tables)
Parameters = dict[str, Any]


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
class ReconcileDocument:
    """``reconcile.json`` (docs/reconcile.md): the verdict, named effects, candidates and gaps first; then the
    gap floor and consistency, per-round goodness of fit, significance rule, empirical corrections and notes; the
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
    goodness_of_fit: dict[str, Any]
    significance_rule: dict[str, float]
    empirical_corrections: list[EmpiricalCorrection]
    notes: list[str]
    families: dict[str, dict[str, Any]]
    excluded_steps: list[ExcludedStep]
    corners: dict[str, Any] | None = optional()
    unexplained: dict[str, Any] | None = optional()
    not_comparable: NotComparable | None = optional()
    ambiguity: Ambiguity | None = optional()
