"""What the camera looks at, and the operator prompt at every change of it.

A campaign chains procedures whose targets differ (the bare wall, the
slanted-edge chart, the white sheet over it, the checkerboard, a Böhler star,
a material plate on the hoist, the face mask). Every change of the mounted
target between two consecutive steps needs a person, so every such step must
carry an operator prompt: procedures write their own (with the target's
set-up, e.g. a star's gap to the wall); :func:`with_target_prompts` adds one
where a procedure starts on a target the previous step did not use (e.g. the
chart after a wall sweep, or the bare wall after the checkerboard). The lab's
resting state, before the first step, is the bare white wall.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

from procedures.steps import Step

RESTING_TARGET = "wall"

TARGET_NAMES = {
    "wall": "bare white wall",
    "slanted_edge": "slanted-edge chart",
    "white_sheet": "white sheet over the slanted-edge chart",
    "checkerboard": "checkerboard",
    "boehler_star": "Boehler star",
    "face_mask": "silicone face mask",
}


def mounted_target(step: Step) -> str:
    """The target as the operator sees it: ``"72-segment Boehler star"``, ``"ptfe plate"``, ...

    Two consecutive steps with different mounted targets need a target change.
    """
    if step.target == "boehler_star" and "segments" in step.target_params:
        return f"{step.target_params['segments']}-segment {TARGET_NAMES['boehler_star']}"
    return TARGET_NAMES.get(step.target, f"{step.target} plate")


def change_prompt(previous: str, step: Step) -> str:
    """The prompt for a change from the mounted target ``previous`` to the target of ``step``."""
    if step.target == RESTING_TARGET:
        return f"remove the {previous}: the camera must see the {TARGET_NAMES[RESTING_TARGET]} only"
    return f"remove the {previous} and mount the {mounted_target(step)}"


def with_target_prompts(steps: Iterable[Step]) -> list[Step]:
    """``steps`` with a prompt added to every step whose mounted target differs from the previous
    step's (from the resting bare wall for the first step) and that has no prompt of its own."""
    result = []
    previous = TARGET_NAMES[RESTING_TARGET]
    for step in steps:
        current = mounted_target(step)
        if current != previous and not step.prompt:
            step = dataclasses.replace(step, prompt=change_prompt(previous, step))
        result.append(step)
        previous = current
    return result


def confirm_mounted_prompt(step: Step) -> str:
    """The prompt that re-confirms the mounted target before a resumed run continues at ``step``."""
    if step.target == RESTING_TARGET:
        return (f"resuming at {step.step_id}: check that the camera sees the {TARGET_NAMES[RESTING_TARGET]} "
                "and that nothing else is in its view")
    return f"resuming at {step.step_id}: check that the {mounted_target(step)} is still mounted as for the earlier steps"
