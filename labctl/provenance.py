"""Who wrote a file and when: labctl's version and the current time, as run files, reports and indexes
record them (docs/runfile.md)."""

from __future__ import annotations

from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version


def labctl_version() -> str:
    """The installed labctl's version (package metadata), ``0+unknown`` when labctl is not installed."""
    try:
        return version("labctl")
    except PackageNotFoundError:
        return "0+unknown"


def now_iso() -> str:
    """Current UTC time, ISO 8601 with milliseconds."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")
