"""Serial device emulators on real pseudo-terminals, for testing the drivers in ``drivers/``.

Each emulator speaks its device's documented protocol on the slave side of an
``os.openpty()`` pair (:attr:`~sim.emulators.pty_device.PtyDevice.port`), moves or
measures in real time, and can inject the faults the drivers must handle.
"""

from sim.emulators.dimetix import DimetixEmulator
from sim.emulators.grbl import GrblEmulator
from sim.emulators.pty_device import PtyDevice
from sim.emulators.zaber import ZaberEmulator

__all__ = ["DimetixEmulator", "GrblEmulator", "PtyDevice", "ZaberEmulator"]
