"""Writing a finished matplotlib figure as a PNG file of the report."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def save_png(fig: Any, path: Path, dpi: int) -> Path:
    """Write ``fig`` to ``path`` (its folder created if missing) at ``dpi`` and close it, so a report of many
    figures does not keep them all in memory; returns ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
