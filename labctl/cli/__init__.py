"""The ``labctl`` command line: one module per command group, all errors mapped to exit codes."""

from labctl.cli.app import cli, main

__all__ = ["cli", "main"]
