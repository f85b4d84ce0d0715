"""What every effect module provides.

``NAME`` (the docs/simulation.md name), ``TECHNOLOGIES`` (``tof`` and/or
``stereo``), ``SOURCE`` (where the formula comes from), ``Params`` (a strict
pydantic model: units in the field names, defaults, valid ranges) and the pure
function(s) the sensor pipeline calls at the point where the effect acts. An
effect present in a model's ``[effects]`` table is on, absent is off.
"""

from __future__ import annotations

from procedures.steps import StrictModel


class EffectParams(StrictModel):
    """Base of every effect's parameters (unknown keys are refused)."""
