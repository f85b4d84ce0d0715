"""Device overrides on resume: a serial port that renumbered, a robot with a new address.

The campaign is stored in the run file, so ``labctl resume RUN.h5 --port
laser=/dev/ttyUSB3`` changes a device's connection without touching it. Every
override is appended to the run file's ``device_overrides_json`` attribute
(a JSON list of ``{"time", "role", "field", "value", "previous"}``), and a
later resume applies the recorded ones first, so the run keeps the new port
until it is overridden again.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from typing import Any

from labctl.errors import InputError
from labctl.run.config import Campaign

ATTRIBUTE = "device_overrides_json"
FIELDS = {"port": ("stage", "laser"), "host": ("robot",)}


def parse_overrides(field: str, items: Iterable[str]) -> dict[str, str]:
    """``ROLE=VALUE`` items of option ``--<field>`` as {role: value}; InputError naming a bad item or role."""
    roles = FIELDS[field]
    parsed: dict[str, str] = {}
    for item in items:
        role, sep, value = item.partition("=")
        if not sep or not value:
            raise InputError(f"--{field} {item!r}: expected ROLE=VALUE, e.g. --{field} {roles[0]}=...")
        if role not in roles:
            raise InputError(f"--{field} {item!r}: unknown role {role!r}; --{field} applies to {', '.join(roles)}")
        if role in parsed:
            raise InputError(f"--{field}: {role} is given twice")
        parsed[role] = value
    return parsed


def recorded_overrides(attrs: Mapping[str, Any], where: str) -> list[dict[str, Any]]:
    """The override history of a run file (empty when there is none)."""
    text = attrs.get(ATTRIBUTE)
    if text is None:
        return []
    try:
        history = json.loads(str(text))
    except json.JSONDecodeError as exc:
        raise InputError(f"{where}: attribute {ATTRIBUTE} is not valid JSON ({exc})") from None
    if not isinstance(history, list) or not all(isinstance(e, dict) and {"role", "field", "value"} <= e.keys()
                                                for e in history):
        raise InputError(f"{where}: attribute {ATTRIBUTE} is not a list of role/field/value entries")
    return history


def apply_overrides(campaign: Campaign, overrides: Iterable[tuple[str, str, str]], where: str) -> Campaign:
    """``campaign`` with every (role, field, value) applied to ``[devices.<role>]``, in order."""
    devices = campaign.devices
    for role, field, value in overrides:
        config = getattr(devices, role)
        if config is None:
            raise InputError(f"--{field} {role}={value}: the campaign stored in {where} has no [devices.{role}]")
        devices = devices.model_copy(update={role: config.model_copy(update={field: value})})
    return campaign.model_copy(update={"devices": devices})


def history_entries(campaign: Campaign, overrides: Iterable[tuple[str, str, str]], time: str) -> list[dict[str, Any]]:
    """History entries for ``overrides`` applied on top of ``campaign`` (which gives the previous values)."""
    return [
        {"time": time, "role": role, "field": field, "value": value,
         "previous": getattr(getattr(campaign.devices, role), field)}
        for role, field, value in overrides
    ]


def encode_history(history: list[dict[str, Any]]) -> str:
    """The attribute's text."""
    return json.dumps(history)
