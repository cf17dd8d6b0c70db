"""The simulated station's default camera gives sessions every step can process.

``SimulatedStation()`` without a world (as ``kogei mock`` and ``kogei gui --mock`` set it up): its frames
are the documented 240 x 160 pixels and its chart frame, opening every placement, is found by
``cv2.mcc`` with all 24 patches usable on every pass -- the world's own edge-to-edge grid chart, the
former default, is reported as partly outside the frame.  The detected card's corners are compared with
the renderer's ground truth.
"""

from __future__ import annotations

import numpy as np
import pytest

from app.workflows.chart import chart_report
from mocks.station import SimulatedStation
from mocks.world import STATION_CHART_LAYOUT, STATION_FRAME_SIZE, World
from processing.errors import InputError


def test_the_default_station_chart_is_found_on_every_pass(tmp_path):
    with SimulatedStation(root=tmp_path / "station", seed=0, hotfolder_interval_s=0.01) as st:
        assert (st.world.width, st.world.height) == STATION_FRAME_SIZE == (240, 160)
        assert st.world.chart_layout == STATION_CHART_LAYOUT == "classic24"
        truth = st.world.frame("chart").chart_corners
        for placement in (1, 2, 3):
            st.place(placement)
            report = chart_report(st.shoot())
            assert report["method"] == "mcc" and len(report["patches"]) == 24, (placement, report["warnings"])
            assert all(p["usable"] for p in report["patches"]), (placement, report["warnings"])
            found = np.asarray(report["corners"], dtype=float)          # photosites, as the truth
            assert np.abs(np.sort(found, axis=0) - np.sort(truth, axis=0)).max() < 4.0, (found, truth)


def test_the_grid_chart_of_worlds_default_is_not_found_whole(tmp_path):
    """Why the station does not use World's default: the same check fails on the grid chart."""
    with SimulatedStation(World.hawk(2_000, width=240, height=160), root=tmp_path / "station", seed=0,
                          hotfolder_interval_s=0.01) as st:
        st.place(1)
        with pytest.raises(InputError, match="partly outside the frame"):
            chart_report(st.shoot())
