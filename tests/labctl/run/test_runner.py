"""The runner: retries, identical data under faults, safe state on every failure path."""

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.errors import DroppedFrame
from labctl.cli import main
from labctl.errors import Interrupted, RunAborted
from labctl.run.config import load_campaign
from labctl.run.lab import build_sim_lab
from labctl.run.operator import Operator
from labctl.run.progress import Reporter
from labctl.run.runner import Runner
from labctl.run.store import RunWriter
from sim.model import load_model

MANY_STEPS = """
[[procedure]]
kind = "offset_calibration"
frames = 6

[[procedure]]
kind = "depth_sweep"
start_mm = 500
stop_mm = 3500
step_mm = 250
frames = 6
"""


def invoke(*args) -> int:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    return info.value.code


def step_arrays(path: Path) -> dict[str, dict[str, np.ndarray]]:
    with h5py.File(path, "r") as f:
        return {
            sid: {name: g[name][()] for name in ("x", "y", "z", "intensity", "confidence")}
            for sid, g in f["steps"].items()
        }


def test_faults_are_retried_and_data_are_identical(tmp_path, write_campaign, small_model):
    model = small_model()
    clean = write_campaign("clean.toml", procedures=MANY_STEPS)
    faulty = write_campaign(
        "faulty.toml", procedures=MANY_STEPS,
        faults="""[sim.faults]
serial_timeout = 0.4
serial_garbage = 0.4
camera_disconnect = 0.4
dropped_frame = 0.4
""",
    )
    assert invoke("run", clean, "--sim", "--model", model, "-o", tmp_path / "a.h5", "--quiet") == 0
    assert invoke("run", faulty, "--sim", "--model", model, "-o", tmp_path / "b.h5", "--quiet") == 0
    a, b = step_arrays(tmp_path / "a.h5"), step_arrays(tmp_path / "b.h5")
    assert a.keys() == b.keys() and len(a) == 14
    for sid in a:
        for name in a[sid]:
            np.testing.assert_array_equal(a[sid][name], b[sid][name], err_msg=f"{sid}/{name}")
    kinds = set()
    with h5py.File(tmp_path / "b.h5", "r") as f:
        import json

        for g in f["steps"].values():
            faults = json.loads(g.attrs["faults_json"])
            assert g.attrs["retries"] == len(faults)
            kinds |= {x["kind"] for x in faults}
        laser_a = {k: v.attrs["laser_distance_mm"] for k, v in h5py.File(tmp_path / "a.h5", "r")["steps"].items()}
        laser_b = {k: v.attrs["laser_distance_mm"] for k, v in f["steps"].items()}
    assert kinds == {"serial_timeout", "serial_garbage", "camera_disconnect", "dropped_frame"}
    assert laser_a == laser_b


class StuckCamera:
    """Wraps a camera so that every frame after the first few is dropped."""

    def __init__(self, inner, good_frames: int):
        self.inner, self.good = inner, good_frames
        self.safe_calls = 0

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def safe_state(self):
        self.safe_calls += 1

    def capture(self, count, first_index=0):
        for frame in self.inner.capture(count, first_index):
            if self.good <= 0:
                raise DroppedFrame("camera", "no frame")
            self.good -= 1
            yield frame


class DarkCorner(StuckCamera):
    """Wraps a camera so that its top left pixel is never valid."""

    def __init__(self, inner):
        super().__init__(inner, 10**9)

    def capture(self, count, first_index=0):
        for frame in self.inner.capture(count, first_index):
            frame.z[0, 0] = np.nan
            yield frame


def build(tmp_path, write_campaign, small_model, wrap=None):
    campaign, text = load_campaign(write_campaign(procedures=MANY_STEPS))
    model, model_text = load_model(small_model())
    lab = build_sim_lab(campaign, model, 1)
    if wrap:
        lab.camera = wrap(lab.camera)
    for dev in lab.devices().values():
        dev.connect()
    run = RunWriter.create(
        tmp_path / "r.h5", campaign_toml=text, simulated=True,
        devices={r: (d.identity(), d.settings()) for r, d in lab.devices().items()},
        camera=lab.camera.info(), steps=len(campaign.steps()), sim=(model_text, 1),
    )
    reporter = Reporter(quiet=True)
    return Runner(campaign, lab, run, reporter, Operator(True, reporter.message)), run, lab


def test_persistent_fault_aborts_safely_and_keeps_complete_steps(tmp_path, write_campaign, small_model):
    """A camera that stops delivering frames (a simulated camera wrapped to drop every frame after the 15th)."""
    runner, run, lab = build(tmp_path, write_campaign, small_model, wrap=lambda cam: StuckCamera(cam, 15))
    with pytest.raises(RunAborted, match="capture stuck at frame 3 of 6 after 5 attempts: no frame; the camera stopped "
                                         "delivering frames: check its cable, power and network"):
        runner.execute()
    assert lab.camera.safe_calls == 1
    run.close()
    with h5py.File(tmp_path / "r.h5", "r") as f:
        assert f.attrs["status"] == "aborted"
        assert "capture stuck" in f.attrs["status_reason"]
        complete = [k for k, g in f["steps"].items() if g.attrs["complete"]]
    assert complete == ["00000_offset_calibration", "00001_depth_sweep"]
    assert invoke("resume", tmp_path / "r.h5", "--quiet") == 0  # the camera delivers again
    with h5py.File(tmp_path / "r.h5", "r") as f:
        assert f.attrs["status"] == "complete" and all(g.attrs["complete"] for g in f["steps"].values())


class CtrlCStage:
    """A stage whose third move is interrupted by Ctrl-C."""

    def __init__(self, inner):
        self.inner, self.moves, self.safe_calls = inner, 0, 0

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def safe_state(self):
        self.safe_calls += 1

    def move_to(self, position):
        self.moves += 1
        if self.moves == 3:
            raise KeyboardInterrupt
        self.inner.move_to(position)


def test_ctrl_c_brings_devices_to_safe_state_and_resume_completes(tmp_path, write_campaign, small_model):
    runner, run, lab = build(tmp_path, write_campaign, small_model)
    lab.stage = stage = CtrlCStage(lab.stage)
    with pytest.raises(Interrupted, match="labctl resume"):
        runner.execute()
    assert stage.safe_calls == 1
    run.close()
    with h5py.File(tmp_path / "r.h5", "r") as f:
        assert f.attrs["status"] == "aborted"
        assert len(f["steps"]) == 2
    assert invoke("resume", tmp_path / "r.h5", "--quiet") == 0
    campaign, model = write_campaign("ref.toml", procedures=MANY_STEPS), small_model()
    assert invoke("run", campaign, "--sim", "--model", model, "--seed", 1, "-o", tmp_path / "ref.h5", "--quiet") == 0
    resumed, reference = step_arrays(tmp_path / "r.h5"), step_arrays(tmp_path / "ref.h5")
    assert sorted(resumed) == sorted(reference)
    for sid in reference:
        np.testing.assert_array_equal(resumed[sid]["z"], reference[sid]["z"])
    with h5py.File(tmp_path / "r.h5", "r") as f:
        assert f.attrs["status"] == "complete"


def test_resume_of_complete_run_does_nothing(tmp_path, write_campaign, small_model):
    out = tmp_path / "r.h5"
    assert invoke("run", write_campaign(), "--sim", "--model", small_model(), "-o", out, "--quiet") == 0
    before = step_arrays(out)
    assert invoke("resume", out) == 0
    assert step_arrays(out).keys() == before.keys()


def test_few_percent_faults_give_identical_key_figures(tmp_path, write_campaign, small_model):
    """The issue's case: [sim.faults] of a few percent, same key figures, retries in the run file."""
    import json

    model = small_model(width=96, height=72)
    long_sweep = MANY_STEPS.replace("step_mm = 250", "step_mm = 100")  # 31 sweep positions
    rates = "\n".join(f"{kind} = 0.04" for kind in ("serial_timeout", "serial_garbage", "camera_disconnect", "dropped_frame"))
    clean = write_campaign("clean.toml", procedures=long_sweep)
    faulty = write_campaign("faulty.toml", procedures=long_sweep, faults=f"[sim.faults]\n{rates}\n")
    for campaign, name in ((clean, "clean"), (faulty, "faulty")):
        assert invoke("run", campaign, "--sim", "--model", model, "-o", tmp_path / f"{name}.h5", "--quiet") == 0
        assert invoke("evaluate", tmp_path / f"{name}.h5", "-o", tmp_path / name, "--quiet", "--no-pdf") == 0
    docs = {name: json.loads((tmp_path / name / "keyfigures.json").read_text()) for name in ("clean", "faulty")}
    assert docs["clean"]["figures"] == docs["faulty"]["figures"]
    assert docs["clean"]["figures"]["z_precision_q90_mm"]["value"] is not None
    with h5py.File(tmp_path / "faulty.h5", "r") as f:
        retries = sum(int(g.attrs["retries"]) for g in f["steps"].values())
    with h5py.File(tmp_path / "clean.h5", "r") as f:
        assert sum(int(g.attrs["retries"]) for g in f["steps"].values()) == 0
    assert retries >= 3


class BuggyCamera(StuckCamera):
    def capture(self, count, first_index=0):
        raise ValueError("unexpected frame format")


def test_unexpected_error_still_reaches_safe_state(tmp_path, write_campaign, small_model):
    runner, run, lab = build(tmp_path, write_campaign, small_model, wrap=lambda cam: BuggyCamera(cam, 0))
    with pytest.raises(ValueError, match="unexpected frame format"):
        runner.execute()
    assert lab.camera.safe_calls == 1
    run.close()
    with h5py.File(tmp_path / "r.h5", "r") as f:
        assert f.attrs["status"] == "aborted"
        assert "internal error: ValueError" in f.attrs["status_reason"]


ALIGNMENT = """
[[procedure]]
kind = "alignment"
frames = 3
{extra}
"""


class ScriptedOperator(Operator):
    """An operator who answers the alignment question from a script (and confirms every prompt)."""

    def __init__(self, answers: list[str], report) -> None:
        super().__init__(True, report)
        self.answers = answers
        self.questions: list[str] = []

    def choose(self, question: str, options: list[str]) -> str:
        self.questions.append(question)
        return self.answers.pop(0)


def alignment_runner(tmp_path, write_campaign, small_model, operator_answers, extra=""):
    campaign, text = load_campaign(write_campaign(procedures=ALIGNMENT.format(extra=extra)))
    model, model_text = load_model(small_model())
    lab = build_sim_lab(campaign, model, 1)
    for dev in lab.devices().values():
        dev.connect()
    run = RunWriter.create(
        tmp_path / "a.h5", campaign_toml=text, simulated=True,
        devices={r: (d.identity(), d.settings()) for r, d in lab.devices().items()},
        camera=lab.camera.info(), steps=len(campaign.steps()), sim=(model_text, 1),
    )
    messages: list[str] = []
    operator = ScriptedOperator(list(operator_answers), messages.append)
    reporter = Reporter(quiet=True)
    reporter.message = messages.append  # type: ignore[method-assign]
    return Runner(campaign, lab, run, reporter, operator), run, lab, operator, messages


def test_alignment_is_measured_again_until_the_operator_accepts(tmp_path, write_campaign, small_model):
    """Each stack shows the four field depths and the tilt; 'measure again' replaces the stack, the
    accepted one is recorded once with its fields and tilt."""
    runner, run, lab, operator, messages = alignment_runner(
        tmp_path, write_campaign, small_model, ["measure again", "measure again", "accept"], extra="field_px = 4")
    runner.execute()
    run.close()
    assert len(operator.questions) == 3 and not operator.answers
    shown = [m for m in messages if m.startswith("alignment fields (mm): top left")]
    assert len(shown) == 3 and all("implied tilt about x" in m for m in shown)
    with h5py.File(tmp_path / "a.h5", "r") as f:
        steps = list(f["steps"])
        assert steps == ["00000_alignment"]
        attrs = f["steps/00000_alignment"].attrs
        assert attrs["complete"] and set(json.loads(attrs["alignment_fields_json"])) == {
            "top_left", "top_right", "bottom_left", "bottom_right"}
        assert abs(attrs["tilt_x_deg"]) < 0.5 and abs(attrs["tilt_y_deg"]) < 0.5


def test_alignment_field_without_valid_pixels_aborts_with_a_clear_message(tmp_path, write_campaign, small_model):
    """Fields pushed to the very corner of a camera whose corners are dark: the run stops, says which field
    and what to change, and the devices go to their safe state."""
    runner, run, lab, operator, _ = alignment_runner(tmp_path, write_campaign, small_model, ["accept"],
                                                     extra="margin_px = 0\nfield_px = 1")
    lab.camera = DarkCorner(lab.camera)
    with pytest.raises(RunAborted, match=r"alignment: the top left alignment field \(rows 0-0, columns 0-0\) has no "
                                         r"valid pixel; move the fields with margin_px / field_px"):
        runner.execute()
    assert lab.camera.safe_calls == 1 and not operator.questions
