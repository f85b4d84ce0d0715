"""The command line loads the work of a command only when that command runs: ``labctl --help``, ``labctl info`` or
a device command do not wait for reconcile, the evaluation, Dask or the plots to import (several seconds)."""

import json
import subprocess
import sys

#: modules that only some commands need; none of them is imported by merely starting labctl
HEAVY = ("labctl.reconcile.workflow", "labctl.reconcile.null", "labctl.reconcile.confounds", "labctl.evaluation",
         "labctl.batch.orchestrate", "labctl.run.campaign", "labctl.run.store", "labctl.report", "metrics", "sim.model",
         "matplotlib", "dask", "distributed")


def loaded_after(code: str) -> list[str]:
    """The modules a fresh interpreter holds after running ``code``."""
    probe = f"import sys, json\n{code}\nprint(json.dumps(sorted(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True)
    return json.loads(done.stdout.splitlines()[-1])


def heavy(modules: list[str]) -> list[str]:
    return [m for m in modules if any(m == h or m.startswith(h + ".") for h in HEAVY)]


def test_starting_the_command_line_imports_no_command_s_work():
    assert heavy(loaded_after("import labctl.cli")) == []


def test_help_of_every_command_imports_no_command_s_work():
    """``--help`` of labctl, of every command and of every command of a group, the commands read from the CLI."""
    code = ("import contextlib, io\nimport click\nfrom labctl.cli import cli\n"
            "paths = [[]]\n"
            "for name, command in cli.commands.items():\n"
            "    paths.append([name])\n"
            "    if isinstance(command, click.Group):\n"
            "        paths += [[name, sub] for sub in command.commands]\n"
            "assert len(paths) > 20, paths\n"
            "for args in paths:\n"
            "    with contextlib.redirect_stdout(io.StringIO()):\n"
            "        cli.main(args=[*args, '--help'], standalone_mode=False)")
    assert heavy(loaded_after(code)) == []

