"""Masked pairs: two hidden effects that each hide the other from the one-at-a-time search.

Each round scores every candidate alone (beside the effects already named,
``score.Beside``). Two effects hidden together can each fall below the naming
threshold that way: a range scale and a diffuse floor bounce on the blaze-101
scored dBIC 27.1 and 3.2 alone, because where one of them moves the residual
the other's form fits it no better than nothing. When no candidate is
significant alone and the run is not consistent with its noise, the best
``PAIR_PARTNERS`` candidates are each taken as a *partner*: its fitted change
is set beside every other candidate (as a named effect's slopes are), and a
pair is found when the other candidate is significant beside the partner
*and* the partner is significant beside the other's fitted change, each by
the round's own rule (``significant``). The pair whose two conditional scores
sum highest is the one named; both its scores count Schwarz's penalty for
their own parameters, so the pair's evidence is the evidence of the two
parameter sets over none (stepwise selection that considers two terms at once
where single steps stall: Miller 2002, *Subset selection in regression*, chapter 3).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from labctl.reconcile.candidates import Candidate, Context
from labctl.reconcile.residuals import Layout
from labctl.reconcile.score import Beside, Fit, score

#: the best-scored candidates tried as a partner (set by hand: in the three masked pairs of the simulation-based
#: calibration, docs/reconcile.md, one effect had the best single score; the next two cost one scoring round each)
PAIR_PARTNERS = 3


@dataclass(frozen=True)
class MaskedPair:
    """Two candidates each significant beside the other's fitted change; ``first`` the partner."""

    first: tuple[Fit, Candidate]  # the partner, scored beside the second's fitted change
    second: tuple[Fit, Candidate]  # scored beside the partner's fitted change

    @property
    def evidence(self) -> float:
        return self.first[0].score + self.second[0].score


def _beside(named: np.ndarray | None, change: np.ndarray) -> Beside:
    """The named effects' slopes (None: none yet) and one more fitted change, as ``score.Beside``."""
    return Beside.of(change[:, None] if named is None else np.hstack([named, change[:, None]]))


def _conditional(candidate: Candidate, ctx: Context, lay: Layout, beside: Beside, residual: np.ndarray,
                 significant: Callable[[Fit], bool]) -> Fit | None:
    """``candidate`` scored beside ``beside`` (another candidate's fitted change and the named effects; ``residual``
    has them taken out); None unless it is significant there and predicts held-out steps."""
    fit = score(candidate, ctx, lay, residual, beside)
    return fit if fit is not None and fit.loso_gain > 0 and significant(fit) else None


def masked_pair(fits: Sequence[tuple[Fit, Candidate]], ctx: Context, lay: Layout, residual: np.ndarray,
                named: np.ndarray | None, significant: Callable[[Fit], bool],
                say: Callable[[str], None]) -> MaskedPair | None:
    """The best pair of ``fits`` (the round's candidates alone, best first) each significant beside the other
    (None: no pair is); ``residual`` the whitened residual, ``named`` the named effects' slopes (None: none)."""
    best: MaskedPair | None = None
    for partner, partner_candidate in fits[:PAIR_PARTNERS]:
        if not np.any(partner.signature):
            continue
        say(f"scoring the candidates beside {partner.name}")
        beside_partner = _beside(named, partner.signature)
        left = beside_partner.out_of(residual)
        for _, candidate in fits:
            if candidate is partner_candidate:
                continue
            second = _conditional(candidate, ctx, lay, beside_partner, left, significant)
            if second is None:
                continue
            beside_second = _beside(named, second.signature)
            first = _conditional(partner_candidate, ctx, lay, beside_second, beside_second.out_of(residual),
                                 significant)
            if first is None:
                continue
            pair = MaskedPair((first, partner_candidate), (second, candidate))
            if best is None or pair.evidence > best.evidence:
                best = pair
    return best
