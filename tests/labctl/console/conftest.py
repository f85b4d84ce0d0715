"""A simulated run with the live console, as a subprocess, and a headless Chromium driven by Selenium."""

from __future__ import annotations

import os
import queue
import resource
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import SMALL_MODEL, campaign_text

STARTUP_S = 120.0
"""How long a run may take to print the console's URL on 2 loaded cores (imports, numba)."""


class ConsoleRun:
    """``labctl run|resume ... --console`` in a subprocess; its stderr lines are collected as they come."""

    def __init__(self, *args: str | Path) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "labctl", *map(str, args)],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._collect, daemon=True).start()

    def _collect(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            self.stderr.append(line)
            self.lines.put(line)
        self.lines.put(None)  # the run has ended

    def url(self) -> str:
        """The URL the run printed (waits for it)."""
        while True:
            try:
                line = self.lines.get(timeout=STARTUP_S)
            except queue.Empty:
                raise AssertionError(f"no console URL within {STARTUP_S} s:\n{self.output}") from None
            if line is None:
                raise AssertionError(f"the run ended without serving the console:\n{self.output}")
            if line.startswith("console: "):
                return line.split(" ", 1)[1].strip()

    def wait(self, timeout: float = STARTUP_S) -> int:
        """The exit status."""
        return self.process.wait(timeout)

    @property
    def output(self) -> str:
        """Everything printed on stderr so far."""
        return "".join(self.stderr)

    def close(self) -> None:
        """End the run if it still goes (a failed test)."""
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        for stream in (self.process.stdout, self.process.stderr):
            if stream is not None:
                stream.close()


@pytest.fixture
def console_run() -> Iterator[type[ConsoleRun]]:
    """Start runs with :class:`ConsoleRun`; each is ended after the test."""
    started: list[ConsoleRun] = []

    class Tracked(ConsoleRun):
        def __init__(self, *args: str | Path) -> None:
            super().__init__(*args)
            started.append(self)

    yield Tracked
    for run in started:
        run.close()


@pytest.fixture
def small_campaign(tmp_path: Path):
    """A campaign of ``procedures`` on the simulated blaze-101 at 64 x 48 px: (campaign, model) paths."""

    def write(procedures: str) -> tuple[Path, Path]:
        campaign, model = tmp_path / "campaign.toml", tmp_path / "model.toml"
        campaign.write_text(campaign_text(procedures=procedures))
        model.write_text(SMALL_MODEL.format(camera="blaze101", width=64, height=48))
        return campaign, model

    return write


@pytest.fixture
def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[object]:
    """Headless Debian Chromium through chromedriver; skipped, saying what to install, when either is missing.
    Chromium's temporary directories go to one of pytest's (TMPDIR), not to /tmp where they would stay."""
    chromium = shutil.which("chromium")
    chromedriver = shutil.which("chromedriver")
    if chromium is None or chromedriver is None:
        missing = " and ".join(n for n, p in (("chromium", chromium), ("chromedriver", chromedriver)) if p is None)
        pytest.skip(f"no {missing} on PATH: the console's browser tests need Debian's chromium and chromium-driver "
                    "(make's set-up installs them as root: apt-get install chromium chromium-driver)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for argument in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                     "--window-size=1400,900"):
        options.add_argument(argument)
    # chromedriver and Chromium reserve far more address space than the suite's limit (tests/conftest.py) and
    # trap under it: they are started without it (a child keeps the limits it was forked with)
    limits = resource.getrlimit(resource.RLIMIT_AS)
    resource.setrlimit(resource.RLIMIT_AS, (limits[1], limits[1]))
    try:
        environment = {**os.environ, "TMPDIR": str(tmp_path_factory.mktemp("chromium"))}
        driver = webdriver.Chrome(service=Service(chromedriver, env=environment), options=options)
    finally:
        resource.setrlimit(resource.RLIMIT_AS, limits)
    try:
        yield driver
    finally:
        driver.quit()
