"""The live console's options of ``labctl run`` and ``labctl resume`` (docs/console.md)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import click

from labctl.errors import InputError


def echo_err(message: str) -> None:
    """A line on stderr (the console's URL)."""
    click.echo(message, err=True)


def console_options(command: Callable[..., None]) -> Callable[..., None]:
    """``--console``, ``--console-port`` and ``--console-host`` (docs/console.md)."""
    command = click.option("--console-host", metavar="HOST", help="serve the console on this address instead of "
                           "127.0.0.1; the printed URL then carries a token that every request needs")(command)
    command = click.option("--console-port", type=click.IntRange(0, 65535), default=0, show_default=True,
                           help="port of the console (0: any free port)")(command)
    return click.option("--console", "with_console", is_flag=True,
                        help="serve the live operator console (a web page; its URL is printed)")(command)


@contextmanager
def run_console(with_console: bool, host: str | None, port: int) -> Iterator[dict[str, Any]]:
    """The ``observer`` and ``remote`` keyword arguments of a run: a console's, or none without --console."""
    if not with_console:
        if host is not None or port:
            raise InputError("--console-host and --console-port only apply with --console")
        yield {}
        return
    from labctl.console.session import open_console

    with open_console(host or "127.0.0.1", port, echo_err) as console:
        yield {"observer": console.state, "remote": console.remote}
