"""Lamps from a chrome sphere's highlights against a ray-traced synthetic booth (truth: the scene's lamps)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from processing.geometry.lamp_calibration import (
    Lamp,
    LampCalibration,
    LampCalibrationError,
    calibrate_lamps,
    find_highlights,
)
from tests.geometry.sphere_scene import DIST, K, Scene

ANGLES = np.arange(12) * 30.0
POINT = np.array([-200.0, -300.0, 350.0])                 # ~500 mm from the axis
DISTANT = np.array([-0.3, -0.5, 0.8]) / np.linalg.norm([-0.3, -0.5, 0.8])


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


def test_point_lamp_within_2_mm_at_500_mm():
    scene = Scene(point_lamps=[(POINT, 15.0, 1.3)])
    cal = calibrate_lamps(scene.views(ANGLES), K, DIST, scene.room_to_camera, 20.0)
    (lamp,) = cal.lamps
    assert lamp.kind == "point" and lamp.n_observations == 12          # auto chose the point model
    assert np.linalg.norm(lamp.position_mm - POINT) < 2.0
    err = lamp.position_mm - POINT                                    # the covariance is of the right size
    assert np.all(np.abs(err) < 5 * np.sqrt(np.diag(lamp.covariance)))
    assert np.all(cal.circle_miss_mm < 0.1)                           # sphere centres on the table's circle
    assert np.all(cal.sphere_rms_px < 0.15) and np.all(cal.ray_miss_deg < 0.1)


def test_distant_lamp_within_0_2_deg():
    scene = Scene(distant_lamps=[(DISTANT, 1.0, 1.3)])
    cal = calibrate_lamps(scene.views(ANGLES), K, DIST, scene.room_to_camera, 20.0)
    (lamp,) = cal.lamps
    assert lamp.kind == "distant"                                     # auto chose the distant model
    assert _angle_deg(lamp.direction, DISTANT) < 0.2


def test_two_lamps_both_recovered():
    second = np.array([150.0, -380.0, 300.0])
    scene = Scene(point_lamps=[(POINT, 15.0, 1.3), (second, 15.0, 0.9)])
    cal = calibrate_lamps(scene.views(ANGLES), K, DIST, scene.room_to_camera, 20.0)
    assert [lp.kind for lp in cal.lamps] == ["point", "point"]
    assert all(lp.n_observations == 12 for lp in cal.lamps)          # each frame's two highlights split 1 + 1
    found = sorted((lp.position_mm for lp in cal.lamps), key=lambda p: p[0])
    assert np.linalg.norm(found[0] - POINT) < 2.0 and np.linalg.norm(found[1] - second) < 2.0


def test_a_point_and_a_distant_lamp_are_told_apart():
    sun = np.array([0.5, -0.6, 0.6]) / np.linalg.norm([0.5, -0.6, 0.6])
    scene = Scene(point_lamps=[(POINT, 15.0, 1.3)], distant_lamps=[(sun, 1.0, 1.0)])
    cal = calibrate_lamps(scene.views(ANGLES), K, DIST, scene.room_to_camera, 20.0)
    by_kind = {lp.kind: lp for lp in cal.lamps}
    assert sorted(by_kind) == ["distant", "point"]
    assert np.linalg.norm(by_kind["point"].position_mm - POINT) < 2.0
    assert _angle_deg(by_kind["distant"].direction, sun) < 0.2


def test_highlights_with_a_mask_are_the_lamp_reflections():
    scene = Scene(point_lamps=[(POINT, 15.0, 1.3)])
    img = scene.render(scene.sphere_centre_room(0.0))
    vv, uu = np.mgrid[0:640, 0:960]
    mask = (uu - 742.0) ** 2 + (vv - 295.0) ** 2 < 140.0 ** 2
    (hl,) = find_highlights(img, mask, clip_level=1.0, name="f")
    bright = np.argwhere(img > 0.5)                                   # the lamp's reflection (backdrop 0.25)
    assert np.linalg.norm(hl - bright.mean(axis=0)[::-1]) < 1.0


def test_round_trip_through_json_and_untrusted_input():
    lamp = Lamp("key", "point", position_mm=POINT, covariance=np.eye(3) * 0.1, spectrum="3200K", n_observations=12)
    cal = LampCalibration([lamp, Lamp("sun", "distant", direction=DISTANT, spectrum=6500.0)], 20.0,
                          ["a", "b"], np.array([0.1, 0.1]), np.array([0.01, 0.02]), np.array([0.0, 0.01]))
    back = LampCalibration.from_dict(json.loads(json.dumps(cal.to_dict())))
    assert [lp.kind for lp in back.lamps] == ["point", "distant"] and back.lamps[0].spectrum == "3200K"
    assert np.allclose(back.lamps[0].position_mm, POINT) and np.allclose(back.lamps[1].direction, DISTANT)
    bad = cal.to_dict()
    bad["lamps"][0]["position_mm"] = [1, 2]
    twice, skew = cal.to_dict(), cal.to_dict()
    twice["lamps"][1]["name"] = "key"
    skew["lamps"][0]["covariance"] = [[1, 2, 0], [0, 1, 0], [0, 0, 1]]
    for data, msg in ((bad, "key.position_mm"), (twice, "same name"), (skew, "symmetric positive"), ({**cal.to_dict(), "version": 9}, "version 9"),
                      ({**cal.to_dict(), "schema": "x"}, "not a lamp calibration"), ([], "JSON object"),
                      ({**cal.to_dict(), "lamps": []}, "non-empty list")):
        with pytest.raises(LampCalibrationError, match=msg):
            LampCalibration.from_dict(data)


def test_no_highlight_is_refused():
    scene = Scene()                                                   # no lamp
    with pytest.raises(LampCalibrationError, match="frame00: no highlight"):
        calibrate_lamps(scene.views(ANGLES[:3]), K, DIST, scene.room_to_camera, 20.0)


def test_saturated_highlight_is_refused():
    scene = Scene(point_lamps=[(POINT, 15.0, 5.0)])
    img = np.minimum(scene.render(scene.sphere_centre_room(0.0)), 1.0)
    with pytest.raises(LampCalibrationError, match="f: saturated highlight: shoot the lamp calibration at a shorter"):
        find_highlights(img, (742.0, 295.0, 150.0), clip_level=1.0, name="f")


def test_too_few_views_and_missing_sphere_are_refused():
    scene = Scene(point_lamps=[(POINT, 15.0, 1.3)])
    views = scene.views(ANGLES[:3])
    with pytest.raises(LampCalibrationError, match="at least 3 frames"):
        calibrate_lamps(views[:2], K, DIST, scene.room_to_camera, 20.0)
    with pytest.raises(LampCalibrationError, match="no frame shows 2 highlights"):
        calibrate_lamps(views, K, DIST, scene.room_to_camera, 20.0, n_lamps=2)
    views[1] = ("empty.png", 30.0, np.full((640, 960), 0.25))
    with pytest.raises(LampCalibrationError, match="sphere not found in frame empty.png"):
        calibrate_lamps(views, K, DIST, scene.room_to_camera, 20.0)


def test_a_lamp_that_moved_is_refused_as_inconsistent():
    before = Scene(point_lamps=[(POINT, 15.0, 1.3)]).views(ANGLES[:6])
    moved = Scene(point_lamps=[(POINT + [80.0, -60.0, 0.0], 15.0, 1.3)]).views(ANGLES[6:], seed=6)
    with pytest.raises(LampCalibrationError, match=r"miss it by .* deg RMS, expected about"):
        calibrate_lamps(before + moved, K, DIST, Scene().room_to_camera, 20.0)
