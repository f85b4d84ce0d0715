"""Real adapters and simulated devices cannot drift apart: each derives from its base class in
``drivers/device.py`` and has every method of its protocol in ``drivers/protocols.py`` with the
protocol's signature; a simulated device has no public method its protocol lacks."""

import importlib
import inspect
import pkgutil
from collections.abc import Iterator, Mapping
from typing import Any

import pytest

import drivers
import sim.devices
from drivers.camera.blaze import PylonBlazeCamera
from drivers.camera.flexx2 import Flexx2Camera
from drivers.camera.gentl import GenTLCamera
from drivers.camera.realsense import RealSenseCamera
from drivers.device import BaseDevice, CameraDevice, LinkedDevice, SerialDevice
from drivers.errors import DeviceError
from drivers.laser.dimetix import DimetixLaser
from drivers.protocols import DepthCamera, Device, Frame, LinearStage, RangeMeter, Robot
from drivers.robot.ur5e import UR5eRobot
from drivers.stage.grbl import GrblStage
from drivers.stage.zaber import ZaberStage
from sim.devices import SimCamera, SimDevice, SimLaser, SimRobot, SimStage

# (protocol, base class, class)
IMPLEMENTATIONS = [
    (LinearStage, SerialDevice, GrblStage),
    (LinearStage, SerialDevice, ZaberStage),
    (LinearStage, SimDevice, SimStage),
    (RangeMeter, SerialDevice, DimetixLaser),
    (RangeMeter, SimDevice, SimLaser),
    (Robot, LinkedDevice, UR5eRobot),
    (Robot, SimDevice, SimRobot),
    (DepthCamera, CameraDevice, PylonBlazeCamera),
    (DepthCamera, CameraDevice, GenTLCamera),
    (DepthCamera, CameraDevice, Flexx2Camera),
    (DepthCamera, CameraDevice, RealSenseCamera),
    (DepthCamera, CameraDevice, SimCamera),
]
SIMULATED = [(protocol, cls) for protocol, _, cls in IMPLEMENTATIONS if cls.__module__ == "sim.devices"]


def protocol_methods(protocol: type) -> dict[str, Any]:
    """The public methods a protocol and the protocols it extends declare."""
    methods: dict[str, Any] = {}
    for klass in reversed(protocol.__mro__):
        if getattr(klass, "_is_protocol", False) and klass.__module__ == "drivers.protocols":
            methods.update({name: value for name, value in vars(klass).items() if inspect.isfunction(value)})
    return {name: value for name, value in methods.items() if not name.startswith("_")}


def signature(function: Any) -> inspect.Signature:
    """The signature with its annotations resolved, so spelling differences do not count."""
    return inspect.signature(function, eval_str=True)


def drift(protocol: type, cls: type) -> list[str]:
    """What ``cls`` lacks of ``protocol``, or declares with another signature."""
    problems = []
    for name, declared in protocol_methods(protocol).items():
        implemented = inspect.getattr_static(cls, name, None)
        if not inspect.isfunction(implemented):
            problems.append(f"{cls.__name__} lacks {protocol.__name__}.{name}")
        elif signature(implemented) != signature(declared):
            problems.append(f"{cls.__name__}.{name}{signature(implemented)} != {protocol.__name__}.{name}{signature(declared)}")
    return problems


def device_classes() -> set[type]:
    """Every concrete class with ``connect`` and ``safe_state`` defined in ``drivers`` or ``sim/devices.py``."""
    modules = [importlib.import_module(m.name) for m in pkgutil.walk_packages(drivers.__path__, "drivers.")]
    return {
        cls
        for module in [*modules, sim.devices]
        for _, cls in inspect.getmembers(module, inspect.isclass)
        if cls.__module__ == module.__name__
        and hasattr(cls, "connect")
        and hasattr(cls, "safe_state")
        and not getattr(cls, "_is_protocol", False)
        and not inspect.isabstract(cls)
    }


def test_every_device_is_checked():
    """A new adapter or simulated device must be listed above, with its protocol and base class."""
    assert device_classes() == {cls for _, _, cls in IMPLEMENTATIONS}
    protocols = {protocol for protocol, _, _ in IMPLEMENTATIONS}
    assert protocols == {LinearStage, RangeMeter, Robot, DepthCamera}
    assert all(issubclass(protocol, Device) for protocol in protocols)


@pytest.mark.parametrize(("protocol", "base", "cls"), IMPLEMENTATIONS, ids=lambda v: getattr(v, "__name__", ""))
def test_device_derives_from_its_base_and_matches_its_protocol(protocol, base, cls):
    assert issubclass(cls, base) and issubclass(base, BaseDevice)
    assert not inspect.isabstract(cls), f"{cls.__name__} leaves {sorted(cls.__abstractmethods__)} unimplemented"
    assert drift(protocol, cls) == []


@pytest.mark.parametrize(("protocol", "cls"), SIMULATED, ids=lambda v: getattr(v, "__name__", ""))
def test_simulated_device_offers_nothing_beyond_its_protocol(protocol, cls):
    """A method only the simulation had would let the runner depend on what no real adapter offers."""
    offered = {name for name, value in inspect.getmembers(cls, inspect.isfunction) if not name.startswith("_")}
    assert offered <= set(protocol_methods(protocol))


def test_drift_is_detected():
    class Drifted(CameraDevice):
        """Adds a parameter to ``capture``, renames ``configure``'s and lacks ``info``."""

        def connect(self) -> None: ...

        def close(self) -> None: ...

        def safe_state(self) -> None: ...

        def settings(self) -> Mapping[str, Any]: ...

        def configure(self, exposure: float | None, settings: Mapping[str, Any]) -> None: ...

        def capture(self, count: int, first_index: int = 0, timeout_s: float = 1.0) -> Iterator[Frame]: ...

    problems = drift(DepthCamera, Drifted)
    assert len(problems) == 2 and "Drifted.configure" in problems[0] and "Drifted.capture" in problems[1]
    assert inspect.isabstract(Drifted) and Drifted.__abstractmethods__ == {"info"}


def test_identity_before_connect_names_the_device_and_its_port():
    laser = DimetixLaser("/dev/ttyUSB7")
    with pytest.raises(DeviceError) as raised:
        laser.identity()
    assert str(raised.value) == "Dimetix laser on /dev/ttyUSB7: not connected: call connect() first"
    assert laser.port == laser.connection == "/dev/ttyUSB7"
