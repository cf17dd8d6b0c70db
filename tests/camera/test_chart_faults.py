"""The station's chart fault switches end in the chart pipeline's errors (hot-folder frames, real DNG files)."""

from __future__ import annotations

import pytest

from mocks.fake_gphoto2 import read_config
from mocks.station import SimulatedStation, parse_faults
from mocks.world import World
from processing.camera.chart_detection import ChartOutsideError, detect_chart
from processing.camera.chart_sampling import ChartRejectedError, check_patches, sample_patches
from processing.camera.raw_decode import decode_raw


def test_chart_outside_and_saturation_switches(tmp_path):
    world = World.hawk(2_000, chart_layout="classic24", width=600, height=400, spectral_step=20.0,
                       chart_placement={"size": 0.6, "rotation_deg": 5})
    with SimulatedStation(world, root=tmp_path / "st", seed=3, hotfolder_interval_s=0.0) as st:
        img = decode_raw(st.shoot())                                   # first frame: the chart, in view
        assert check_patches(sample_patches(img, detect_chart(img))).usable.all()
        st.apply_faults(parse_faults("world.chart_outside=1"))
        # the fake gphoto2 renders from its configuration: the switch reaches it too
        assert read_config(st.config_path)["world"]["chart_placement"]["center"][0] == pytest.approx(0.8)
        st.place(2)
        with pytest.raises(ChartOutsideError, match="partly outside the frame"):
            detect_chart(decode_raw(st.shoot()))
        st.apply_faults(parse_faults("world.chart_outside=0,hotfolder.saturate=1"))
        st.place(3)
        img = decode_raw(st.shoot())
        with pytest.raises(ChartRejectedError, match=r"clipped: lower the exposure"):
            check_patches(sample_patches(img, detect_chart(img)))
