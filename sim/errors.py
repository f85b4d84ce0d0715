"""The simulator's one error for bad input: an invalid model file or text."""

from __future__ import annotations


class ModelError(ValueError):
    """A simulation model (file or text) is invalid; the message names the file and the field."""
