"""The camera model's docstring examples (metrics/optics.py) hold: each is worked by hand from its formula."""

import doctest

import metrics.optics


def test_docstring_examples_hold() -> None:
    result = doctest.testmod(metrics.optics, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0
    assert result.attempted >= 9  # every example of every public name ran
