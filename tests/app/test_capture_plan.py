"""Capture plans: the action list is complete, unique and ordered; camera angles snap to steps;
swatch plans; bad plans are refused with the parameter named."""

from __future__ import annotations

import pytest

from app.capture.runner import CapturePlan


def test_scan_actions_are_unique_and_complete():
    plan = CapturePlan("scan", steps=10, passes=3, camera_angles_deg=(0.0, 90.0, 180.0, 270.0))
    ids = [a.id for a in plan.actions()]
    assert len(ids) == len(set(ids)) == 3 * (1 + 10 + 4)
    for p in (1, 2, 3):
        acts = plan.pass_actions(p)
        assert acts[0].kind == "chart" and acts[0].angle_deg == 0.0      # the chart comes first
        assert [a.index for a in acts if a.kind == "profile"] == list(range(10))
        assert all(a.pass_no == p for a in acts)


def test_camera_angles_snap_to_the_nearest_step_and_follow_their_profile():
    plan = CapturePlan("scan", steps=8, passes=1, camera_angles_deg=(100.0, -45.0, 359.0))
    acts = plan.pass_actions(1)
    frames = [(a.index, a.angle_deg) for a in acts if a.kind == "frame"]
    # steps are 45 deg apart: 100 -> 90, -45 -> 315, 359 -> 0 (wraps)
    assert sorted(frames) == [(0, 90.0), (1, 315.0), (2, 0.0)]
    for k, a in enumerate(acts):
        if a.kind == "frame":
            prev = acts[k - 1]
            assert prev.angle_deg == a.angle_deg and prev.kind in ("profile", "frame")


def test_profiles_only_and_no_chart():
    assert all(a.kind == "profile" for a in CapturePlan("scan", steps=4, passes=2, camera=False).actions())
    acts = CapturePlan("scan", steps=4, passes=1, chart=False, camera_angles_deg=(0.0,)).actions()
    assert [a.kind for a in acts].count("chart") == 0 and [a.kind for a in acts].count("frame") == 1


def test_swatch_plan():
    acts = CapturePlan("swatch", steps=6, passes=1).actions()
    assert [a.kind for a in acts] == ["chart"] * 16 + ["frame"] * 6     # sixteen chart frames by default
    assert [a.angle_deg for a in acts[16:]] == [0.0, 60.0, 120.0, 180.0, 240.0, 300.0]


def test_round_trip():
    plan = CapturePlan("scan", steps=7, passes=2, camera_angles_deg=(30.0,), lasers=(1, 2))
    assert CapturePlan.from_dict(plan.to_dict()) == plan


@pytest.mark.parametrize("kw,match", [
    ({"kind": "spiral"}, "plan kind"),
    ({"steps": 0}, "steps must be"),
    ({"steps": 2.5}, "steps must be"),
    ({"passes": 0}, "passes must be"),
    ({"passes": 100}, "passes must be"),
    ({"camera_angles_deg": (float("nan"),)}, "finite"),
    ({"kind": "swatch", "camera": False}, "needs the camera"),
])
def test_bad_plans(kw, match):
    with pytest.raises(ValueError, match=match):
        CapturePlan(**kw)


def test_swatch_chart_frames_have_their_own_ids():
    # several chart frames per swatch pass, each a distinct capture (resumable like the others); scan plans
    # keep their single pNN/chart
    acts = CapturePlan("swatch", steps=2, passes=2, chart_frames=3).actions()
    charts = [a for a in acts if a.kind == "chart"]
    assert [a.id for a in charts] == [f"p0{p}/chart/0{k}" for p in (1, 2) for k in range(3)]
    assert len({a.stem for a in charts if a.pass_no == 1}) == 3
    assert [a.id for a in CapturePlan("scan", steps=2, passes=1).actions() if a.kind == "chart"] == ["p01/chart"]
    assert CapturePlan("swatch").chart_frames == 16 and CapturePlan("scan").chart_frames == 1
    plan = CapturePlan("swatch", steps=5, passes=1, chart_frames=2)
    assert CapturePlan.from_dict(plan.to_dict()) == plan
    # a manifest written before the setting existed was taken with one chart frame
    old = {k: v for k, v in CapturePlan("swatch", steps=5).to_dict().items() if k != "chart_frames"}
    assert CapturePlan.from_dict(old).chart_frames == 1


@pytest.mark.parametrize("bad", [0, 100, 2.0, True, "4"])
def test_bad_chart_frames_are_refused(bad):
    with pytest.raises(ValueError, match="chart_frames"):
        CapturePlan("swatch", chart_frames=bad)


# ---------------------------------------------------------------------------- calibration plans
def test_a_camera_calibration_plan_shoots_the_board_at_twelve_angles_per_placement_without_a_chart():
    plan = CapturePlan("camera-calibration")
    assert (plan.steps, plan.passes, plan.chart) == (12, 3, False)
    frames = [a for a in plan.actions() if a.kind == "frame"]
    assert len(frames) == 36 and not [a for a in plan.actions() if a.kind != "frame"]
    assert [a.angle_deg for a in plan.pass_actions(2)] == [30.0 * i for i in range(12)]
    assert plan.board == {"dictionary": "DICT_5X5_100", "squares_x": 7, "squares_y": 5, "square_mm": 8.0,
                          "marker_mm": 6.0}
    # the board travels with the plan into the manifest and back
    assert CapturePlan.from_dict(plan.to_dict()) == plan


def test_a_lamp_calibration_plan_is_one_pass_of_twelve_frames_and_keeps_the_sphere_radius():
    plan = CapturePlan("lamp-calibration", sphere_radius_mm=20.0)
    assert (plan.steps, plan.passes, plan.chart) == (12, 1, False)
    assert [a.id for a in plan.actions()][:2] == ["p01/frame/00", "p01/frame/01"]
    assert CapturePlan.from_dict(plan.to_dict()).sphere_radius_mm == 20.0


def test_a_scan_plan_shoots_frames_every_30_degrees_by_default():
    plan = CapturePlan("scan", steps=120, passes=1)
    frames = [a for a in plan.actions() if a.kind == "frame"]
    assert [a.angle_deg for a in frames] == [30.0 * i for i in range(12)]


@pytest.mark.parametrize("kw, match", [
    ({"kind": "camera-calibration", "board": {"squares_x": 9}}, "board must have exactly the fields"),
    ({"kind": "scan", "board": {"squares_x": 9}}, "board is for a camera-calibration plan"),
    ({"kind": "lamp-calibration", "sphere_radius_mm": -2.0}, "sphere_radius_mm must be a radius"),
    ({"kind": "lamp-calibration", "camera": False}, "needs the camera"),
])
def test_calibration_plan_fields_are_checked(kw, match):
    with pytest.raises(ValueError, match=match):
        CapturePlan(**kw)


def test_holdout_burst_shoots_the_held_out_angles_again():
    from app.workflows.holdout_validation import holdout_frames

    plan = CapturePlan("scan", steps=36, passes=2, holdout_burst=4)     # 12 camera angles, every 30 deg
    frames = [a for a in plan.actions() if a.kind == "frame"]
    burst = [a for a in plan.actions() if a.kind == "burst"]
    # the burst's angles are the ones the validation holds out (the same rule on the same angles)
    held = holdout_frames([a.id for a in frames], [a.angle_deg for a in frames], every=4)
    assert {f"p{a.pass_no:02d}/frame/{a.index:02d}" for a in burst} == held
    assert sorted({a.angle_deg for a in burst}) == [60.0, 180.0, 300.0]
    assert len(burst) == 2 * 3 * 3 and {a.shot for a in burst} == {1, 2, 3}
    ids = [a.id for a in plan.actions()]
    assert len(ids) == len(set(ids))
    k = ids.index("p01/frame/02")                     # the burst follows its first frame at the same angle
    assert ids[k + 1:k + 4] == ["p01/frame/02/burst/01", "p01/frame/02/burst/02", "p01/frame/02/burst/03"]
    assert [a.stem for a in burst[:1]] == ["frame_02_burst_01"]
    assert CapturePlan.from_dict(plan.to_dict()) == plan
    # without a burst the plan and its stored form are what they were before bursts existed
    single = CapturePlan("scan", steps=36, passes=2)
    assert "holdout_burst" not in single.to_dict() and not single.burst_frames()
    assert [a.id for a in single.actions()] == [i for i in ids if "/burst/" not in i]


@pytest.mark.parametrize("kw, match", [({"holdout_burst": 0}, "holdout_burst"), ({"holdout_burst": 2.5}, "holdout_burst"),
                                       ({"holdout_every": 1, "holdout_burst": 2}, "holdout_every"),
                                       ({"kind": "swatch", "holdout_burst": 2}, "scan plan")])
def test_bad_holdout_burst_is_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        CapturePlan(**{"kind": "scan", **kw})
