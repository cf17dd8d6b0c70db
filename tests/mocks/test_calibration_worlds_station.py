"""The station takes the calibration worlds: placements pick the board's tilts and the ball's offsets,
and the fake gphoto2 rebuilds them from its configuration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rawpy

from drivers.camera_gphoto2 import Gphoto2Camera
from mocks.board_world import BoardWorld
from mocks.fake_gphoto2 import _world, read_config
from mocks.mirror_world import MirrorWorld
from mocks.station import SimulatedStation


def test_board_and_mirror_placements_through_the_station(tmp_path):
    board = BoardWorld.charuco(width=240, height=160, spectral_step=50.0)
    with SimulatedStation(board, root=tmp_path / "station", seed=2, hotfolder_interval_s=0.01) as st:
        for n in (2, 3, 1):
            pose = st.place(n)
            assert np.array_equal(pose, board.fixed_placement_pose(n))
            tilt = np.degrees(np.arccos((pose[:3, :3] @ [0.0, 0.0, -1.0])[2]))
            assert abs(tilt - board.tilts_deg[n - 1]) < 1e-9
            again = _world(read_config(st.config_path)["world"], Path(st.config_path))
            assert isinstance(again, BoardWorld) and np.allclose(again.pose, pose)
        st.place(3)
        assert st.shoot().exists()                       # the chart
        obj = st.shoot()
        with rawpy.imread(str(obj)) as raw:
            assert raw.raw_image_visible.shape == (160, 240)
        cam = Gphoto2Camera(tmp_path / "session", executable=st.gphoto2_path, timeout_s=120)
        shot = cam.capture("board")                      # an object frame through the fake gphoto2
        with rawpy.imread(str(shot)) as raw:
            got = raw.raw_image_visible.astype(float)
        with rawpy.imread(str(obj)) as raw:
            hot = raw.raw_image_visible.astype(float)
        assert np.abs(got - hot).mean() < 0.05 * hot.mean()   # the same board frame (only the noise differs)

        ball = MirrorWorld.mirror_sphere(20.0, (35.0, 45.0), width=240, height=160, spectral_step=50.0)
        st.put_object(ball)
        assert st.pose[0, 3] == 35.0
        pose = st.place(2)
        assert pose[0, 3] == 45.0 and pose[2, 3] == 20.0
        again = _world(read_config(st.config_path)["world"], Path(st.config_path))
        assert isinstance(again, MirrorWorld) and np.allclose(again.sphere_centre_mm(0.0), [45.0, 0.0, 20.0])
