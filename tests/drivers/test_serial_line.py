"""SerialLine over a real pseudo-terminal: line splitting, bounded waits, garbage, a vanished port."""

from __future__ import annotations

import fcntl
import os
import struct
import termios
import time
import tty
from collections.abc import Iterator

import pytest

from drivers.errors import DeviceError, DeviceVanished, SerialGarbage, SerialTimeout
from drivers.serial_line import SerialLine


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, str]]:
    """The master end (written by the test) and the slave path (opened by SerialLine)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    yield master, os.ttyname(slave)
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


def wait_readable(port: str, count: int) -> None:
    """Until ``count`` bytes written to the master end can be read at ``port`` (the kernel passes them on
    asynchronously), within a generous deadline."""
    fd = os.open(port, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        deadline = time.monotonic() + 30.0
        while struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0] < count:
            assert time.monotonic() < deadline, f"{count} bytes not readable at {port}"
            time.sleep(0.01)
    finally:
        os.close(fd)


def open_line(port: str, terminator: bytes = b"\r\n", timeout_s: float = 10.0) -> SerialLine:
    """A SerialLine on ``port``; the reply timeout is generous (a loaded machine may pass the bytes late) where
    a test expects no timeout."""
    line = SerialLine(f"test device on {port}", port, 115200, terminator=terminator, timeout_s=timeout_s)
    line.open()
    return line


def test_lines_are_split_and_the_rest_stays_buffered(pty_pair: tuple[int, str]) -> None:
    master, port = pty_pair
    line = open_line(port)
    os.write(master, b"first\r\nsecond\r\nthi")
    assert line.read_line("a first line") == "first"
    assert line.read_line("a second line") == "second"
    os.write(master, b"rd\r\n")
    assert line.read_line("a third line") == "third"
    line.close()


def test_lf_terminator_strips_a_trailing_cr(pty_pair: tuple[int, str]) -> None:
    master, port = pty_pair
    line = open_line(port, terminator=b"\n")
    os.write(master, b"ok\r\nok\n")
    assert [line.read_line("ok"), line.read_line("ok")] == ["ok", "ok"]


@pytest.mark.realtime
def test_a_partial_reply_times_out_with_what_arrived(pty_pair: tuple[int, str]) -> None:
    master, port = pty_pair
    line = open_line(port, timeout_s=0.15)
    os.write(master, b"g0g+000")
    wait_readable(port, len(b"g0g+000"))
    start = time.monotonic()
    with pytest.raises(SerialTimeout, match=r"expected 'g0g\.\.\.'; got b'g0g\+000'") as caught:
        line.read_line("'g0g...'")
    assert 0.15 <= time.monotonic() - start < 5.0  # bounded (about 0.15 s; a loaded machine may take longer)
    assert port in str(caught.value)


def test_non_ascii_bytes_are_garbage(pty_pair: tuple[int, str]) -> None:
    master, port = pty_pair
    line = open_line(port)
    os.write(master, b"\x8f\xfe#\r\nfine\r\n")
    with pytest.raises(SerialGarbage, match="non-ASCII reply"):
        line.read_line("a reply")
    assert line.read_line("a reply") == "fine"


def test_discard_input_returns_and_drops_stale_bytes(pty_pair: tuple[int, str]) -> None:
    master, port = pty_pair
    line = open_line(port, timeout_s=0.2)
    os.write(master, b"late\r\n")
    wait_readable(port, len(b"late\r\n"))
    assert line.discard_input() == b"late\r\n"
    with pytest.raises(SerialTimeout):
        line.read_line("nothing")


def test_a_vanished_port_is_fatal(pty_pair: tuple[int, str]) -> None:
    master, port = pty_pair
    line = open_line(port)
    os.close(master)
    with pytest.raises(DeviceVanished, match=f"the port {port} failed or vanished waiting for a reply") as caught:
        line.read_line("a reply")
    assert not isinstance(caught.value, SerialTimeout) and caught.value.connection == port


def test_unopened_and_missing_ports() -> None:
    line = SerialLine("meter on /dev/does-not-exist", "/dev/does-not-exist", 9600, terminator=b"\n", timeout_s=0.1)
    with pytest.raises(DeviceError, match="not connected"):
        line.write(b"x", "x")
    with pytest.raises(DeviceError, match="does-not-exist: cannot open the port at 9600 baud"):
        line.open()
