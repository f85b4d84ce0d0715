"""Set-up check run by ``make`` after installing the package: every native SDK labctl and its
tests load must import, else stop at once with the command that installs what is missing.

Most native libraries come inside the wheels; the one system library pyrealsense2 links
against, ``libusb-1.0.so.0``, comes from the ``libusb-package`` wheel when the system has none
(drivers.libusb), so a fresh Debian/Ubuntu machine needs no root. Should an import still fail
on a missing shared library (``libX.so.N: cannot open shared object file``, dlopen(3)), the
check names it; a known Debian package is installed with apt-get when running as root
(``--install``), otherwise the exact command is printed and the exit status is 1.

Optional test tools (``TEST_TOOLS``) are installed the same way when missing (as root, ``--install``);
without root the check names the command and still succeeds: the tests that use them run without them or
say why they cannot.

Usage: ``python -m labctl.setup_check [--install] [--system-only]``
(``--system-only``: do not fall back to the wheel's libusb, check the system's libraries).
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import shutil
import subprocess
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

from drivers.libusb import DEBIAN_PACKAGE, SONAME, ensure_libusb

MODULES = (
    "numpy", "scipy", "cv2", "h5py", "hdf5plugin", "blosc", "numba", "matplotlib", "serial",
    "rtde_control", "rtde_receive", "pyrealsense2", "harvesters.core", "genicam.genapi", "pypylon.pylon",
)
"""Modules with native code that labctl or its tests import (pmd's roypy is optional: not on PyPI)."""
DEBIAN_PACKAGES = {SONAME: DEBIAN_PACKAGE}
"""Shared libraries the check knows the Debian/Ubuntu package of."""
TEST_TOOLS = {"strace": "strace", "chromium": "chromium", "chromedriver": "chromium-driver"}
"""Programs the tests use, with their Debian/Ubuntu package: strace lets tests/labctl/run/test_crash_points.py
kill a run at a chosen write (without it, at random times only); Chromium prints the report to report.pdf
(``labctl evaluate``; tests/labctl/report/test_report_layout.py checks the PDF); chromedriver lets Selenium
drive it for the live console's browser tests (tests/labctl/console)."""
_MISSING_LIBRARY = re.compile(r"([\w.+-]+\.so(?:\.[\w.]+)?): cannot open shared object file")


@dataclass(frozen=True)
class Failure:
    module: str
    error: str
    library: str | None  # the missing shared library, if that is the cause


def check_imports(modules: Sequence[str]) -> list[Failure]:
    """Import each module; the failures, with the missing shared library where the error names one."""
    failures = []
    for name in modules:
        try:
            with warnings.catch_warnings():  # SWIG-generated SDK modules warn on import
                warnings.simplefilter("ignore", DeprecationWarning)
                importlib.import_module(name)
        except ImportError as exc:
            found = _MISSING_LIBRARY.search(str(exc))
            failures.append(Failure(name, str(exc), found.group(1) if found else None))
    return failures


def apt_command(packages: Sequence[str], as_root: bool) -> list[str]:
    """The apt-get command installing ``packages`` (with sudo unless running as root)."""
    command = ["apt-get", "install", "-y", *sorted(set(packages))]
    return command if as_root else ["sudo", *command]


def _apt_install(packages: Sequence[str]) -> bool:
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    print(f"set-up check: installing {' '.join(packages)} with apt-get", file=sys.stderr)
    return subprocess.run(["apt-get", "update", "-qq"], env=env).returncode == 0 and \
        subprocess.run(apt_command(packages, True), env=env).returncode == 0


def check_test_tools(install: bool) -> list[str]:
    """Install the missing optional test tools with apt-get when ``install`` (as root); the packages of those
    still missing, each named on stderr with the command that installs it."""
    missing = [package for tool, package in TEST_TOOLS.items() if shutil.which(tool) is None]
    if missing and install and shutil.which("apt-get"):
        _apt_install(missing)
        missing = [package for tool, package in TEST_TOOLS.items() if shutil.which(tool) is None]
    if missing:
        as_root = hasattr(os, "geteuid") and os.geteuid() == 0
        print(f"set-up check: optional test tools missing (their tests run without them): {' '.join(missing)}; "
              f"run: {' '.join(apt_command(missing, as_root))}", file=sys.stderr)
    return missing


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m labctl.setup_check", description=__doc__.split("\n\n")[0])
    parser.add_argument("--install", action="store_true", help="as root: apt-get install missing system libraries")
    parser.add_argument("--system-only", action="store_true", help="do not use the libusb shipped by libusb-package")
    args = parser.parse_args(argv)
    ensure_libusb(bundled=not args.system_only)
    as_root = hasattr(os, "geteuid") and os.geteuid() == 0
    check_test_tools(install=args.install and as_root)
    failures = check_imports(MODULES)
    if not failures:
        print("set-up check: every SDK imports")
        return 0
    for failure in failures:
        print(f"set-up check: cannot import {failure.module}: {failure.error}", file=sys.stderr)
    packages = [DEBIAN_PACKAGES[f.library] for f in failures if f.library in DEBIAN_PACKAGES]
    unknown = sorted({f.library for f in failures if f.library and f.library not in DEBIAN_PACKAGES})
    others = [f.module for f in failures if f.library is None]
    if packages and args.install and as_root and shutil.which("apt-get") and not unknown and not others:
        if _apt_install(packages):  # check again in a fresh process: this one has already failed to load the library
            rest = [a for a in (argv if argv is not None else sys.argv[1:]) if a != "--install"]
            return subprocess.run([sys.executable, "-m", "labctl.setup_check", *rest]).returncode
    if packages:
        print(f"set-up check: run: {' '.join(apt_command(packages, as_root))}", file=sys.stderr)
    for library in unknown:
        print(f"set-up check: install the system package that provides {library} "
              f"(Debian/Ubuntu: apt-file search {library})", file=sys.stderr)
    if others:
        print(f"set-up check: reinstall the Python packages: .venv/bin/python -m pip install -e '.[dev]' "
              f"(failed: {', '.join(others)})", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
