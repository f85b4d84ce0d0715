"""Code tables transcribed from vendor manuals (one TOML file per document; see each file's header)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

MANUALS = Path(__file__).parent


def load(name: str) -> dict[str, Any]:
    """The parsed table ``name`` (e.g. ``"zaber_ascii.toml"``)."""
    with (MANUALS / name).open("rb") as file:
        return tomllib.load(file)
