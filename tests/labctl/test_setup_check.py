"""The set-up check ``make`` runs after installing: on this machine's real libraries, in fresh processes."""

from __future__ import annotations

import os
import subprocess
import sys

from labctl.setup_check import apt_command


def _check(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "labctl.setup_check", *args], capture_output=True, text=True, timeout=300)


def _system_has_libusb() -> bool:
    """Independent of the code under test: can a fresh interpreter dlopen the system's libusb?"""
    probe = "import ctypes; ctypes.CDLL('libusb-1.0.so.0')"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True).returncode == 0


def test_every_sdk_imports_with_or_without_the_system_libusb():
    result = _check()
    assert result.returncode == 0, result.stderr
    assert "every SDK imports" in result.stdout


def test_without_the_wheel_libusb_a_missing_system_library_stops_with_the_apt_command():
    """``--system-only`` checks the system's libraries alone: on a machine without libusb-1.0-0 (a fresh
    Debian/Ubuntu) the check must stop at once naming pyrealsense2, the library and the exact command."""
    result = _check("--system-only")
    if _system_has_libusb():
        assert result.returncode == 0, result.stderr
    else:
        assert result.returncode == 1
        assert "cannot import pyrealsense2" in result.stderr
        assert "libusb-1.0.so.0: cannot open shared object file" in result.stderr
        prefix = "" if os.geteuid() == 0 else "sudo "
        assert f"run: {prefix}apt-get install -y libusb-1.0-0" in result.stderr


def test_apt_command_uses_sudo_unless_root():
    assert apt_command(["libusb-1.0-0", "libusb-1.0-0"], as_root=True) == ["apt-get", "install", "-y", "libusb-1.0-0"]
    assert apt_command(["libusb-1.0-0"], as_root=False) == ["sudo", "apt-get", "install", "-y", "libusb-1.0-0"]


def test_a_missing_optional_test_tool_is_named_with_its_command_and_the_check_still_passes(tmp_path):
    """With a PATH holding neither strace, Chromium, chromedriver nor apt-get (so nothing can be installed, even as
    root), the check names them and the command that installs them, and succeeds: the tests that use them say so."""
    result = subprocess.run([sys.executable, "-m", "labctl.setup_check", "--install"], capture_output=True, text=True,
                            timeout=300, env={**os.environ, "PATH": str(tmp_path)})
    assert result.returncode == 0, result.stderr
    assert "every SDK imports" in result.stdout
    prefix = "" if os.geteuid() == 0 else "sudo "
    assert "optional test tools missing" in result.stderr and (
        f"run: {prefix}apt-get install -y chromium chromium-driver strace" in result.stderr)
