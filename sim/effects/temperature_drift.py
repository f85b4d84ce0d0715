"""temperature_drift: warm-up drift of the range, Delta r(t) = delta_mm exp(-t / tau_s) + sum_i d_i exp(-t / tau_i).

The optional ``terms`` (each a ``delta_mm`` and a ``tau_s``) add further time
constants: the sensor die warms within minutes, the housing and lens mount
within tens of minutes, so a warm-up is a sum of exponentials, one per
thermal time constant of a lumped thermal network (first-order lag per node).
t is the device time of the frame (seconds since the camera started). A
camera reaches its steady state after a few tau; the steady offset itself is
``range_offset``. Source: self-heating is a
known ToF error (Thesis 2024, Table 3-2; Chiabrando et al. 2009).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from pydantic import Field

from sim.effects.base import Effect, EffectParams, Observed, RunHoldings


class Term(EffectParams):
    delta_mm: float = Field(ge=-100.0, le=100.0, description="this term's range error at t = 0, mm")
    tau_s: float = Field(gt=0.0, le=86400.0, description="its time constant, s")


class Params(EffectParams):
    delta_mm: float = Field(5.0, ge=-100.0, le=100.0, description="range error at t = 0, mm")
    tau_s: float = Field(600.0, gt=0.0, le=86400.0, description="time constant, s")
    terms: list[Term] = Field(default_factory=list, description="further exponential terms")


def offset_mm(t_s: float, p: Params) -> float:
    """Range error of a frame taken ``t_s`` seconds after start."""
    t = max(t_s, 0.0)
    return p.delta_mm * math.exp(-t / p.tau_s) + sum(term.delta_mm * math.exp(-t / term.tau_s) for term in p.terms)


def capture(params: Mapping[str, Any], run: RunHoldings) -> str:
    """The capture that separates the drift's amplitude and time constant and that ``run`` does not hold: a
    position seen again three time constants later; where the run has that, stacks of the first position
    during the first time constant; where it has both, a capture that tells the time from the distance."""
    tau = float(params.get("tau_s", 600.0))
    first = run.first_position
    if not run.repeated_after(3 * tau):
        return (f"repeat the {first} position later in the run (after about {3 * tau:.0f} s, three time constants) "
                "and start capturing right after power-on: the drift's amplitude and time constant separate "
                "only when the same position is seen warm and settled")
    early = run.early_stacks(tau)
    if early < 3:
        return (f"short stacks of the {first} position from power-on through the first {tau:.0f} s (one time "
                f"constant; the run has {early} there): the drift's amplitude shows only while it changes")
    return run.time_capture(3 * tau)


EFFECT = Effect(
    "temperature_drift",
    ("tof", "stereo"),
    Params,
    "Chiabrando et al. 2009; Thesis 2024, Table 3-2 (self-heating); further terms: one per thermal time constant",
    observed=Observed("warm_up", fitted=("delta_mm", "tau_s", "terms"), solver_bounds={"tau_s": (1.0, 86400.0)},
                      procedure="depth_sweep", capture=capture),
    frame_offset_mm=offset_mm,
    warm_up_s=lambda p: p.tau_s,  # the first (leading) thermal time constant
)
