"""A run file as NeXus viewers see it, read by silx's NeXus parser (``silx.io.nxdata``, what silx view uses): the
file's default leads to the first complete step, an NXdata group whose signal is the z stack, an image per frame
along the frame times, with the other channels as auxiliary signals and units and long names on every dataset."""

from __future__ import annotations

import h5py
import hdf5plugin  # noqa: F401  (the frames are Blosc-compressed)
import numpy as np
import pytest
from silx.io import nxdata

from labctl.cli import main
from tests.conftest import campaign_text


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("nexus")
    campaign = tmp / "c.toml"
    campaign.write_text(campaign_text())
    with pytest.raises(SystemExit) as info:
        main(["run", str(campaign), "--sim", "-o", str(tmp / "r.h5"), "--quiet"])
    assert info.value.code == 0
    return tmp / "r.h5"


def test_the_default_is_the_first_step_as_an_image_stack(run):
    with h5py.File(run, "r") as f:
        assert f.attrs["NX_class"] == "NXroot" and f["steps"].attrs["NX_class"] == "NXentry"
        default = nxdata.get_default(f)
        assert default is not None and default.group.name == "/steps/" + sorted(f["steps"])[0]
        assert default.signal_dataset_name == "z" and default.signal_is_3d and default.interpretation == "image"
        assert default.is_image  # silx shows a 3-D signal of interpretation "image" as images along its first axis
        assert set(default.auxiliary_signals_dataset_names) == {"intensity", "x", "y", "confidence"}
        assert default.axes_dataset_names[0] == "timestamp"
        np.testing.assert_array_equal(default.signal[0], f[default.group.name]["z"][0])


def test_every_step_is_nxdata_with_units_and_long_names(run):
    with h5py.File(run, "r") as f:
        for step in f["steps"].values():
            assert nxdata.is_valid_nxdata(step), step.name
            for name in ("x", "y", "z", "intensity", "confidence", "timestamp"):
                assert step[name].attrs["units"] and step[name].attrs["long_name"], (step.name, name)
            assert step["z"].attrs["units"] == "mm" and step["timestamp"].attrs["units"] == "s"
