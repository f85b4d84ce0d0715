"""Property-based fuzz of the input files: simulation models and campaigns, taken from the examples and mutated
(keys removed or added, values of the wrong type, out of range, NaN and infinity, lists shortened), never end in
a traceback. Validation either accepts a document or raises the project's own error (``ModelError`` or
``InputError``) with a message; what it accepts, the next stage can use: a model renders a frame, a campaign
plans its steps and its file size. A few of the mutated documents also go through the command line.

Deterministic (derandomized, no example database) and bounded: a few hundred in-process examples and a handful
of command-line runs, well under a minute.
"""

from __future__ import annotations

import copy
import math
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from labctl.cli import main
from labctl.errors import InputError
from labctl.run.config import parse_campaign
from labctl.run.planning import expected_run_bytes, schedule
from sim.errors import ModelError
from sim.model import parse_model
from sim.preview import simulate_frame

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = sorted((ROOT / "examples").glob("*.toml")) + sorted((ROOT / "examples" / "demo").glob("*.toml"))

#: small models (32 x 24, so that every accepted one renders in milliseconds) with every table a model has:
#: the documented example, a model per profile with its built-in effects, and one with many effects on
MODELS: list[dict[str, Any]] = [
    {"camera": "blaze101", "camera_overrides": {"width": 32, "height": 24},
     "lab": {"camera_mount_error_mm": 6.0, "laser_offset_mm": 42.0, "laser_bias_mm": 0.4, "laser_noise_mm": 0.15,
             "laser_resolution_mm": 0.1, "tilt_x_deg": 0.0, "tilt_y_deg": 0.0},
     "effects": {"wiggling": {"amplitude_mm": 4.0, "period_mm": 1500.0}}},
    {"camera": "amt100", "camera_overrides": {"width": 32, "height": 24, "fov_h_deg": 60.0, "noise_mm_at_2m": 0.9},
     "effects": {"defocus": {"hyperfocal_mm": 600.0}, "quantization": {"step_mm": 1.0},
                 "temperature_drift": {"delta_mm": 3.0, "tau_s": 300.0, "terms": [{"delta_mm": 1.0, "tau_s": 60.0}]},
                 "fixed_pattern": {"column_offsets_mm": [0.5, -0.5], "pixel_sigma_mm": 0.2, "grid_px": [32, 24]},
                 "empirical_range": {"range_mm": [500.0, 3000.0], "correction_mm": [1.0, -1.0]},
                 "empirical_pixel_map": {"correction_mm": [[0.0, 1.0], [1.0, 0.0]]}}},
    {"camera": "flexx2", "camera_overrides": {"width": 32, "height": 24, "modulation_mhz": 60.0},
     "effects": {"multipath": {"strength": 0.05, "extra_path_mm": 500.0}, "vignetting": {"exponent": 4.0},
                 "floor_multipath": {"plane": "floor", "distance_mm": 300.0, "reflectance": 0.3},
                 "radial_distortion": {"k1": 0.1, "cloud": True}, "fov_error": {"fov_deg": [57.0, 45.0]},
                 "intensity_related_error": {"error_at_reference_mm": 1.0}}},
    {"camera": "d455", "camera_overrides": {"width": 32, "height": 24, "baseline_mm": 95.0},
     "effects": {"disparity_bias": {"amplitude_px": 0.05, "period_px": 1.0}, "range_scale": {"scale": 0.01},
                 "range_offset": {"offset_mm": 2.0}}},
]
CAMPAIGNS: list[dict[str, Any]] = [tomllib.loads(path.read_text()) for path in EXAMPLES]

#: values of the wrong type or out of any sensible range
ODD_VALUES = st.one_of(
    st.sampled_from([0, -1, -160, 1, 2**70, -(2**70), 0.5, -1e-9, 1e12, -1e12, math.nan, math.inf, -math.inf,
                     "", "abc", "160", "best_focus", True, False, [], [0], [1, 2], [[1.0]], {}, {"a": 1}]),
    st.integers(min_value=-(10**6), max_value=10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=6),
)


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path of a TOML document (tables, list items and leaves)."""
    found = [prefix] if prefix else []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, child in items:
        found += _paths(child, (*prefix, key))
    return found


def _parent(doc: Any, path: tuple[Any, ...]) -> Any:
    node = doc
    for key in path[:-1]:
        node = node[key]
    return node


@st.composite
def mutated(draw: st.DrawFn, bases: list[dict[str, Any]]) -> str:
    """One base document with one to three mutations, as TOML text."""
    doc = copy.deepcopy(draw(st.sampled_from(bases)))
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent, key = _parent(doc, path), path[-1]
        value = parent[key]
        kind = draw(st.sampled_from(["remove", "replace", "scale", "add key", "shorten"]))
        if kind == "remove":
            del parent[key]
        elif kind == "replace":
            parent[key] = draw(ODD_VALUES)
        elif kind == "scale" and isinstance(value, int | float) and not isinstance(value, bool):
            parent[key] = value * draw(st.sampled_from([-1, 0, 1e-9, 1e6, -1e6]))
        elif kind == "add key" and isinstance(value, dict):
            value[draw(st.sampled_from(["colour", "width", "frames", "kind", "x"]))] = draw(ODD_VALUES)
        elif kind == "shorten" and isinstance(value, list) and value:
            del value[draw(st.integers(0, len(value) - 1)):]
    return tomli_w.dumps(doc)


def accepted_or_refused_with_a_message(
    parse: Callable[[str, str], Any], error: type[Exception], text: str
) -> Any | None:
    """``parse(text, "fuzz.toml")``, or None when it refused the text with ``error`` whose message names the
    file and says more than its name."""
    try:
        return parse(text, "fuzz.toml")
    except error as exc:
        assert str(exc).startswith("fuzz.toml") and len(str(exc)) > len("fuzz.toml: ")
        event("refused")
        return None


FUZZ = settings(derandomize=True, database=None, deadline=None, print_blob=False,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.mark.filterwarnings("error::RuntimeWarning")  # an overflow the user's terminal would show
@settings(FUZZ, max_examples=300)
@given(text=mutated(MODELS))
def test_a_mutated_model_is_accepted_and_renders_or_is_refused_with_a_message(text: str) -> None:
    model = accepted_or_refused_with_a_message(parse_model, ModelError, text)
    if model is None:
        return
    profile = model.profile()
    if profile.width * profile.height <= 64 * 48:  # a larger sensor is valid, only slower to render
        x, y, z, intensity, confidence = simulate_frame(model, "wall", distance_mm=1500.0)
        assert z.shape == (profile.height, profile.width)
        event("accepted and rendered")


@settings(FUZZ, max_examples=300)
@given(text=mutated(CAMPAIGNS))
def test_a_mutated_campaign_is_accepted_and_planned_or_is_refused_with_a_message(text: str) -> None:
    campaign = accepted_or_refused_with_a_message(parse_campaign, InputError, text)
    if campaign is None:
        return
    event("accepted and planned")
    planned = schedule(campaign)
    assert len(planned) == len(campaign.steps()) and all(math.isfinite(p.duration_s) for p in planned)
    raw, stored = expected_run_bytes(campaign, campaign.runner.compression)
    assert raw >= 0 and stored >= 0


CLI_CAMPAIGN = """
[campaign]
name = "fuzz"
[devices.camera]
backend = "{backend}"
[devices.stage]
protocol = "zaber"
[devices.laser]
port = "/dev/null"
[[procedure]]
kind = "offset_calibration"
frames = 2
[[procedure]]
kind = "depth_sweep"
start_mm = 1500
stop_mm = 2500
step_mm = 1000
frames = 2
"""
BACKENDS = {"blaze101": "blaze", "amt100": "amt100", "flexx2": "flexx2", "d455": "realsense"}


@settings(FUZZ, max_examples=12,
          suppress_health_check=[*FUZZ.suppress_health_check, HealthCheck.function_scoped_fixture])
@given(text=mutated(MODELS))
def test_labctl_run_and_plan_on_mutated_files_exit_cleanly(text: str, tmp_path_factory, capsys) -> None:
    """End to end: ``labctl run --sim`` with a mutated model exits 0, 1 (the simulated camera saw nothing
    usable) or 2 (refused), never with a traceback; a refused model leaves no run file."""
    directory = tmp_path_factory.mktemp("cli")
    camera = tomllib.loads(text).get("camera")
    backend = BACKENDS.get(camera, "blaze") if isinstance(camera, str) else "blaze"
    (directory / "campaign.toml").write_text(CLI_CAMPAIGN.format(backend=backend))
    (directory / "model.toml").write_text(text)
    run = directory / "run.h5"
    with pytest.raises(SystemExit) as done:
        main(["run", str(directory / "campaign.toml"), "--sim", "--model", str(directory / "model.toml"),
              "-o", str(run), "--quiet"])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    assert done.value.code in (0, 1, 2), err
    if done.value.code == 2:
        assert err.startswith("labctl: error: ") and not run.exists()
    run.unlink(missing_ok=True)
