"""Errors that the command line turns into exit codes (README.md, Command line).

* :class:`InputError` — bad configuration, arguments or files: exit 2, one
  paragraph naming the offending field or file, no traceback.
* :class:`RunAborted` — the run stopped on a device failure: exit 1.
* :class:`Interrupted` — Ctrl-C / SIGTERM / SIGHUP after devices reached a safe state: exit 130.
"""

from __future__ import annotations


class LabctlError(Exception):
    """Base class of errors reported to the user without a traceback."""

    exit_code = 1


class InputError(LabctlError):
    """Invalid user input: configuration, command-line arguments or input files."""

    exit_code = 2


class RunAborted(LabctlError):
    """A run ended early because of a hardware or runtime failure."""

    exit_code = 1


class Interrupted(LabctlError):
    """The operator interrupted the run (Ctrl-C), or it received SIGTERM or SIGHUP (its terminal closed)."""

    exit_code = 130
