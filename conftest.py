"""The examples in the docstrings of metrics/ run as tests (doctests) in every pytest run that reaches metrics/.

Only the modules of metrics/ are collected for doctests: the test suite's own modules and the other packages
are not imported as doctest modules. ``pytest --doctest-modules metrics/`` collects the same examples through
pytest itself (and this hook then stands aside, so that nothing runs twice).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from _pytest.doctest import DoctestModule

METRICS = Path(__file__).parent / "metrics"


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Collector | None:
    """A doctest module for each module of metrics/ (unless ``--doctest-modules`` already collects it)."""
    if parent.config.getoption("doctestmodules", False) or file_path.suffix != ".py" or file_path.parent != METRICS:
        return None
    return DoctestModule.from_parent(parent, path=file_path)
