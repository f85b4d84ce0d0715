"""A prompt waits at the terminal and in the console at once: whichever answers first is taken."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from pathlib import Path

import h5py
import pytest

from tests.labctl.console.test_console_browser import CHART_CAMPAIGN
from tests.pty_terminal import Terminal

pytestmark = pytest.mark.slow


def console_state(url: str) -> dict:
    """The console's state document."""
    with urllib.request.urlopen(url + "state.json", timeout=60) as response:
        return json.load(response)


def test_one_prompt_answered_at_the_terminal_the_next_in_the_console(small_campaign, tmp_path: Path) -> None:
    campaign, model = small_campaign(CHART_CAMPAIGN)
    out = tmp_path / "run.h5"
    terminal = Terminal("run", campaign, "--sim", "--model", model, "--interactive", "--console", "-o", out)
    try:
        url = terminal.expect(r"console: (http://\S+)").group(1)
        terminal.expect(r"OPERATOR: mount the slanted-edge chart.*\n.*Press Enter when done")
        first = console_state(url)["prompt"]
        assert first["question"].startswith("mount the slanted-edge chart") and first["options"] == ["done"]
        terminal.type("\r")  # the terminal answers first
        terminal.expect(r"OPERATOR: cover the slanted-edge chart.*\n.*Press Enter when done")
        second = console_state(url)["prompt"]
        assert second["id"] != first["id"] and second["question"].startswith("cover the slanted-edge chart")
        stale = urllib.request.Request(url + "answer", json.dumps({"prompt": first["id"], "answer": "done"}).encode(),
                                       headers={"X-Labctl": "1"})
        with pytest.raises(urllib.error.HTTPError) as refused:  # the first prompt was answered already
            urllib.request.urlopen(stale, timeout=60)
        assert refused.value.code == 409
        answer = urllib.request.Request(url + "answer", json.dumps({"prompt": second["id"], "answer": "done"}).encode(),
                                        headers={"X-Labctl": "1"})
        with urllib.request.urlopen(answer, timeout=60) as response:
            assert json.load(response)["ok"] is True
        terminal.expect(r"done \(answered in the console\)")
        assert terminal.wait() == 0, terminal.output
    finally:
        terminal.close()
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "complete" and len(f["steps"]) == 3
