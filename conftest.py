"""The examples in the docstrings of metrics/ run as tests (doctests) in every pytest run that reaches metrics/.

Only metrics/ is collected for doctests, so the test suite's own modules and the other packages are not
imported twice. ``pytest --doctest-modules metrics/`` collects the same examples through pytest itself.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from _pytest.doctest import DoctestModule

METRICS = Path(__file__).parent / "metrics"


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Collector | None:
    """A doctest module for each module of metrics/ (unless ``--doctest-modules`` already collects it)."""
    if parent.config.option.doctestmodules or file_path.suffix != ".py" or file_path.parent != METRICS:
        return None
    return DoctestModule.from_parent(parent, path=file_path)
