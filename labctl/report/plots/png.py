"""Writing a finished matplotlib figure as a PNG file of the report."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure


def save_png(fig: Figure, path: Path, dpi: int) -> Path:
    """Write ``fig`` to ``path`` (its folder created if missing) at ``dpi``; returns ``path``.

    The report's figures are built as ``matplotlib.figure.Figure`` directly, not through pyplot: no backend is
    chosen and no global figure list keeps them, so they render the same in the CLI, on Dask workers and in
    tests, and are freed once the caller drops them (PNG is written by matplotlib's Agg renderer)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path
