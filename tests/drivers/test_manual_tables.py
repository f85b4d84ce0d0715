"""The drivers' code tables against the vendors' documented text, not against themselves.

Each table in ``tests/drivers/manuals/`` is transcribed from a vendor document (its
header names the document, section and version, and says where the text was read).
Every documented code must be in the driver's table, nothing else may be, and the
driver's wording must carry the documented meaning (its keywords), so that a swapped or
wrong entry fails. The Zaber file is in turn checked against Zaber's own client library.
"""

from __future__ import annotations

import ast
import inspect

import pytest
from zaber_motion import DeviceDbSourceType, Library
from zaber_motion.ascii import Connection
from zaber_motion.ascii import warning_flags as zaber_warning_flags
from zaber_motion.exceptions import CommandFailedException

from drivers.laser.dimetix import ERROR_CODES
from drivers.stage.zaber import REJECTION_REASONS, WARNING_FLAGS
from sim.emulators import ZaberEmulator
from tests.drivers.manuals import MANUALS, load

ZABER = load("zaber_ascii.toml")
DIMETIX = load("dimetix_error_codes.toml")
FLAGS = {entry["code"]: entry["name"] for entry in ZABER["flag"]}
REASONS = {entry["code"]: entry for entry in ZABER["reason"]}
DIMETIX_CODES = {entry["code"]: entry for entry in DIMETIX["code"]}


def test_documents_are_named_with_section_and_version() -> None:
    for name in ("zaber_ascii.toml", "dimetix_error_codes.toml"):
        header = (MANUALS / name).read_text(encoding="utf-8").split("\n\n")[0]
        assert "Source document:" in header and "section" in header.lower()
    assert "firmware 7" in (MANUALS / "zaber_ascii.toml").read_text(encoding="utf-8")
    assert "V1.06" in (MANUALS / "dimetix_error_codes.toml").read_text(encoding="utf-8")


def test_keywords_are_words_of_the_documented_meaning() -> None:
    for entry in [*ZABER["reason"], *DIMETIX["code"]]:
        for keyword in entry["keywords"]:
            assert keyword.lower() in entry["meaning"].lower(), (entry["code"], keyword)


# -- Zaber -----------------------------------------------------------------------------------


def zaber_motion_flags() -> dict[str, str]:
    """Flag code -> name, read from the docstrings of zaber-motion's ``WarningFlags`` class."""
    names: dict[str, str] = {}
    doc = ""
    (cls,) = ast.parse(inspect.getsource(zaber_warning_flags)).body[-1:]
    assert isinstance(cls, ast.ClassDef)
    for node in cls.body:
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            doc = str(node.value.value).strip().splitlines()[0].strip()
        elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
            names[str(node.value.value)] = doc.rstrip(".")
    return names


def test_zaber_flag_file_matches_zaber_motion() -> None:
    assert zaber_motion_flags() == FLAGS


def test_zaber_reason_file_matches_zaber_motion() -> None:
    """Each reason is injected into the emulator; zaber-motion explains it in its own words."""
    Library.set_device_db_source(DeviceDbSourceType.FILE, "/nonexistent/zaber-device-db.sqlite")
    with ZaberEmulator(mm_per_microstep=0.001) as emulator:
        connection = Connection.open_serial_port(emulator.port, direct=True)
        try:
            for reason, entry in REASONS.items():
                emulator.reject_next(reason)
                with pytest.raises(CommandFailedException) as caught:
                    connection.generic_command("get pos", device=1, axis=1, timeout=3000)
                assert str(caught.value).endswith(f"with {reason}: {entry['meaning']}"), reason
        finally:
            connection.close()


def test_zaber_driver_flags_match_the_manual() -> None:
    assert set(WARNING_FLAGS) == set(FLAGS)
    for code, name in FLAGS.items():
        assert WARNING_FLAGS[code].lower().startswith(name.lower()), (code, name, WARNING_FLAGS[code])


def test_zaber_driver_reasons_match_the_manual() -> None:
    assert set(REJECTION_REASONS) == set(REASONS)
    for code, entry in REASONS.items():
        for keyword in entry["keywords"]:
            assert keyword.lower() in REJECTION_REASONS[code].lower(), (code, keyword, REJECTION_REASONS[code])


# -- Dimetix -----------------------------------------------------------------------------------


def test_dimetix_driver_codes_match_the_manual() -> None:
    assert set(ERROR_CODES) == set(DIMETIX_CODES)
    for code, entry in DIMETIX_CODES.items():
        for keyword in entry["keywords"]:
            assert keyword.lower() in ERROR_CODES[code].lower(), (code, keyword, ERROR_CODES[code])
