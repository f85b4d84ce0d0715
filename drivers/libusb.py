"""libusb-1.0 for librealsense: the system's copy, else the one the ``libusb-package`` wheel ships.

pyrealsense2's extension module links against ``libusb-1.0.so.0`` (an ELF ``DT_NEEDED``
entry). The dynamic loader satisfies a needed library by an object already loaded with that
``DT_SONAME`` (glibc ``dl_open``; ld.so(8), "shared object dependencies"), so loading the
wheel's ``libusb-1.0.so`` (SONAME ``libusb-1.0.so.0``) before ``import pyrealsense2`` lets the
SDK import on a machine without the Debian package ``libusb-1.0-0`` and without root. USB
access to a real camera still needs the udev rules of docs/devices.md.
"""

from __future__ import annotations

import ctypes
import sys

SONAME = "libusb-1.0.so.0"
DEBIAN_PACKAGE = "libusb-1.0-0"


def system_libusb() -> bool:
    """True if the dynamic loader finds the system's ``libusb-1.0.so.0``."""
    try:
        ctypes.CDLL(SONAME)
    except OSError:
        return False
    return True


def ensure_libusb(bundled: bool = True) -> str | None:
    """Make ``libusb-1.0.so.0`` resolvable for pyrealsense2 (Linux); what was loaded, or None.

    The system library wins; with ``bundled`` the copy of the ``libusb-package`` wheel is loaded
    (``RTLD_GLOBAL``) when the system has none. Elsewhere than Linux nothing is done.
    """
    if not sys.platform.startswith("linux"):
        return None
    if system_libusb():
        return SONAME
    if not bundled:
        return None
    try:
        import libusb_package
    except ImportError:
        return None
    path = libusb_package.get_library_path()
    if path is None:
        return None
    ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    return str(path)
