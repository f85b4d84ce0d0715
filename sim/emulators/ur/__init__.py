"""An emulated Universal Robots e-Series controller (UR5e) for ur-rtde over loopback.

:class:`URControllerEmulator` serves the dashboard server, the script ports and RTDE on a
loopback address of its own; :class:`URController` holds the modes, safety state,
program, motion and registers the servers share.
"""

from sim.emulators.ur.controller import SafetyPlane, URController
from sim.emulators.ur.process import URControllerProcess
from sim.emulators.ur.server import URControllerEmulator

__all__ = ["SafetyPlane", "URController", "URControllerEmulator", "URControllerProcess"]
