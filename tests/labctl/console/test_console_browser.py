"""The live console in a real browser (headless Chromium): the page shows the plan and progress, a prompt is
answered by a click and the run goes on, Stop leaves the devices safe and the run file aborted and resumable."""

from __future__ import annotations

import json
import urllib.request
from pathlib import Path

import h5py
import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.support import expected_conditions as ec
from selenium.webdriver.support.ui import WebDriverWait

from tests.conftest import run_labctl
from tests.labctl.run.test_operator_prompts import CHART_CAMPAIGN

pytestmark = pytest.mark.slow

WAIT_S = 120.0
"""Upper bound of every wait for the page (a condition, never a pause): 2 loaded cores."""

ALIGNMENT_CAMPAIGN = """
[[procedure]]
kind = "alignment"
distance_mm = 2000
frames = 3

[[procedure]]
kind = "offset_calibration"
frames = 3
"""


def answer_button(driver, answer: str):
    """The prompt's button for ``answer``, once the prompt shows."""
    return WebDriverWait(driver, WAIT_S).until(
        ec.element_to_be_clickable((By.CSS_SELECTOR, f"#answers button[data-answer='{answer}']")))


def test_the_page_shows_the_plan_and_a_click_answers_the_prompt(browser, console_run, small_campaign, tmp_path: Path):
    campaign, model = small_campaign(CHART_CAMPAIGN)
    out = tmp_path / "run.h5"
    run = console_run("run", campaign, "--sim", "--model", model, "--interactive", "--console", "-o", out)
    url = run.url()
    assert url.startswith("http://127.0.0.1:") and "token" not in url
    browser.get(url)
    button = answer_button(browser, "done")  # the chart is mounted before the first slanted-edge step
    plan = [li.get_attribute("data-step") for li in browser.find_elements(By.CSS_SELECTOR, "#plan li")]
    assert plan == ["00000_offset_calibration", "00001_slanted_edge", "00002_slanted_edge"]
    current = browser.find_element(By.CSS_SELECTOR, "#plan li.current")
    assert current.get_attribute("data-step") == "00001_slanted_edge"
    assert "operator: mount the slanted-edge chart" in current.text
    assert browser.find_element(By.ID, "question").text.startswith("mount the slanted-edge chart")
    assert browser.find_element(By.ID, "frames").text == "3 / 9"
    assert browser.find_element(By.ID, "steps").text == "1 / 3"
    assert browser.find_element(By.ID, "left").text not in ("", "\u2013")
    assert browser.find_element(By.ID, "laser").text.endswith(" mm")
    WebDriverWait(browser, WAIT_S).until(lambda d: d.find_element(By.ID, "depth").get_attribute("naturalWidth") != "0")
    with urllib.request.urlopen(url + "state.json", timeout=WAIT_S) as response:  # a second watcher, at the same time
        assert json.load(response)["prompt"]["options"] == ["done"]
    assert run.process.poll() is None  # the run waits for the operator
    button.click()
    # the run goes on to the next step, whose prompt (the white sheet) is a new one, answered by a click too
    WebDriverWait(browser, WAIT_S).until(ec.text_to_be_present_in_element((By.ID, "question"), "white sheet"))
    assert browser.find_element(By.CSS_SELECTOR, "#plan li.current").get_attribute("data-step") == "00002_slanted_edge"
    answer_button(browser, "done").click()
    assert run.wait() == 0, run.output
    assert run.process.stdout.read().count("done (answered in the console)") == 2
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "complete"
        assert all(step.attrs["complete"] for step in f["steps"].values()) and len(f["steps"]) == 3


def test_stop_in_the_browser_leaves_the_run_safe_aborted_and_resumable(browser, console_run, small_campaign,
                                                                       tmp_path: Path):
    campaign, model = small_campaign(ALIGNMENT_CAMPAIGN)
    out = tmp_path / "run.h5"
    run = console_run("run", campaign, "--sim", "--model", model, "--interactive", "--console", "-o", out)
    browser.get(run.url())
    answer_button(browser, "accept")
    # between stacks the camera streams: the corner fields are live
    WebDriverWait(browser, WAIT_S).until(  # (textContent: the headings are upper-cased by the style sheet)
        ec.text_to_be_present_in_element_attribute((By.ID, "alignment-kind"), "textContent", "(live)"))
    assert "tilt about x" in browser.find_element(By.ID, "alignment").text
    WebDriverWait(browser, WAIT_S).until(
        ec.text_to_be_present_in_element_attribute((By.ID, "frame-label"), "textContent", "(live)"))
    browser.find_element(By.ID, "stop").click()
    WebDriverWait(browser, WAIT_S).until(ec.alert_is_present()).accept()
    assert run.wait() == 130, run.output
    assert "stopped from the console; devices are in their safe state" in run.output
    assert f"Continue with: labctl resume {out}" in run.output
    assert "Traceback" not in run.output
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "aborted"
        assert not any(step.attrs.get("complete", False) for step in f["steps"].values())
    resumed = run_labctl("resume", out, "--quiet", "--console")  # resume serves the console too
    assert resumed.returncode == 0, resumed.stderr
    assert resumed.stderr.startswith("console: http://127.0.0.1:")
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "complete"
        assert list(f["steps"]) == ["00000_alignment", "00001_offset_calibration"]
