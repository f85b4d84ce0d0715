"""Linear translation stages (:class:`~drivers.protocols.LinearStage`): Zaber ASCII and Grbl 1.1."""

from __future__ import annotations

from typing import Any

from drivers.stage.grbl import GrblAlarm, GrblError, GrblStage
from drivers.stage.zaber import ZaberFlagError, ZaberRejection, ZaberStage

__all__ = [
    "GrblAlarm",
    "GrblError",
    "GrblStage",
    "ZaberFlagError",
    "ZaberRejection",
    "ZaberStage",
    "move_stage",
]

PROTOCOLS = {"zaber": ZaberStage, "grbl": GrblStage}


def move_stage(
    port: str,
    protocol: str,
    home: bool = False,
    move_mm: float | None = None,
    **options: Any,
) -> float:
    """Optionally home, optionally move to ``move_mm``, and return the position in mm.

    ``protocol`` is ``"zaber"`` or ``"grbl"``; ``options`` go to the stage's constructor
    (``baud``, ``travel_mm``, and for Zaber ``mm_per_microstep``; for Grbl ``axis``,
    ``feed_mm_min``, ``confirm_unlock``). Without ``travel_mm`` the soft limits are (0, ``move_mm``) or
    (0, 1) mm, so a move to a negative position is refused. The stage is left stopped.
    """
    try:
        stage_class = PROTOCOLS[protocol]
    except KeyError:
        raise ValueError(f"unknown stage protocol {protocol!r}; expected one of {sorted(PROTOCOLS)}") from None
    options.setdefault("travel_mm", (0.0, max(move_mm or 0.0, 1.0)))
    with stage_class(port, **options) as stage:
        if home:
            stage.home()
        if move_mm is not None:
            stage.move_to(move_mm)
        return stage.position_mm()
