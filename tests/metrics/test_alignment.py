"""Alignment fields and implied tilt (Thesis 2024, 4.1.2)."""

import math

import numpy as np
import pytest

from labctl.run.config import parse_campaign
from labctl.run.lab import build_sim_lab
from metrics.alignment import alignment_fields, field_slices
from procedures.steps import Step
from sim.model import parse_model


def wall_cloud(tilt_x_deg: float, tilt_y_deg: float, h: int = 120, w: int = 160):
    """A wall 2000 mm away seen by a pinhole camera turned up by tilt_x and right by tilt_y."""
    fx = (w / 2) / math.tan(math.radians(33.5))
    u, v = np.meshgrid((np.arange(w) - (w - 1) / 2) / fx, (np.arange(h) - (h - 1) / 2) / fx)
    ax, ay = math.radians(tilt_x_deg), math.radians(tilt_y_deg)
    # wall normal in the camera frame after the camera turned: dz/dx = tan(ay), dz/dy = -tan(ax)
    z = 2000.0 / (1 - u * math.tan(ay) + v * math.tan(ax))
    return u * z, v * z, z


@pytest.mark.parametrize("tx,ty", [(0.0, 0.0), (1.5, -0.8), (-2.0, 3.0)])
def test_tilt_from_fields(tx, ty):
    x, y, z = wall_cloud(tx, ty)
    fields = alignment_fields(x, y, z)
    assert fields.tilt_x_deg == pytest.approx(tx, abs=0.01)
    assert fields.tilt_y_deg == pytest.approx(ty, abs=0.01)
    assert set(fields.depths()) == {"top_left", "top_right", "bottom_left", "bottom_right"}


def test_fields_must_fit_and_be_valid():
    with pytest.raises(ValueError, match="do not fit"):
        field_slices(20, 30, field_px=10)
    x, y, z = wall_cloud(0, 0)
    h, w = z.shape
    top, left = max(10, round(0.1 * h)), max(10, round(0.1 * w))
    z[top : top + 10, left : left + 10] = np.nan
    with pytest.raises(ValueError, match="top left alignment field .* has no valid pixel"):
        alignment_fields(x, y, z)
    assert alignment_fields(x, y, z, margin_px=0).fields["top_left"][2] > 0


def test_simulated_tilt_is_recovered_through_the_camera():
    """The simulated lab's residual tilt shows up, with its sign, in the fields of a simulated stack."""
    campaign = parse_campaign('[campaign]\nname="a"\n[devices.camera]\nbackend="blaze"\n[devices.stage]\n'
                              'protocol="zaber"\n[[procedure]]\nkind="alignment"\n')
    model = parse_model('camera = "blaze101"\n[camera_overrides]\nwidth = 160\nheight = 120\n'
                        "[lab]\ntilt_x_deg = 1.5\ntilt_y_deg = -0.8\n")
    lab = build_sim_lab(campaign, model, 2)
    for device in lab.devices().values():
        device.connect()
    lab.camera.world.begin_step(Step(0, "alignment", "wall", 10), 0.0)
    lab.stage.move_to(2000.0)
    frames = list(lab.camera.capture(10))
    x, y, z = (np.nanmean([getattr(f, c) for f in frames], axis=0) for c in ("x", "y", "z"))
    fields = alignment_fields(x, y, z)
    assert fields.tilt_x_deg == pytest.approx(1.5, abs=0.03)
    assert fields.tilt_y_deg == pytest.approx(-0.8, abs=0.03)
