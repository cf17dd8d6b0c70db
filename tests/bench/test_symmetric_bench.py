"""The symmetric-object benchmark's hidden-feature test, on synthetic passes of a known shape.

A cylinder of the vase's belly radius (26 mm, the boss centred at azimuth 0 and 30 mm up, as
:mod:`mocks.turned_objects` places it) is "scanned" as points at every azimuth, or with a band of
azimuths missing; which turns can hide the boss follows from the band's geometry alone.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from bench.symmetric_bench import hidden_feature_turn


def _cylinder(missing_deg: tuple[float, float] | None = None) -> SimpleNamespace:
    az = np.radians(np.arange(0.0, 360.0, 0.25))
    z = np.arange(10.0, 50.0, 0.5)
    a, h = np.meshgrid(az, z)
    pts = np.column_stack([26.0 * np.cos(a.ravel()), 26.0 * np.sin(a.ravel()), h.ravel()])
    if missing_deg is not None:
        deg = np.degrees(a.ravel())
        pts = pts[(deg < missing_deg[0]) | (deg > missing_deg[1])]
    return SimpleNamespace(points=pts, pose=np.eye(4))


def test_a_fully_measured_belly_contradicts_every_turn():
    assert hidden_feature_turn("vase", _cylinder(), _cylinder()) is None


def test_a_turn_that_moves_both_bosses_into_unmeasured_bands_is_found():
    # both passes miss azimuths 150-210 deg; the boss (about 9 deg of arc where it stands >= 0.5 mm)
    # lands wholly inside the band for turns of about 160-200 deg in either direction
    t = hidden_feature_turn("vase", _cylinder((150.0, 210.0)), _cylinder((150.0, 210.0)))
    assert t is not None and 155.0 <= t <= 205.0


def test_one_pass_measuring_the_landing_place_is_enough():
    # the source misses the band, the target measured it: the source's boss, turned, lands on the target
    assert hidden_feature_turn("vase", _cylinder(), _cylinder((150.0, 210.0))) is None


def test_other_objects_have_no_boss():
    assert hidden_feature_turn("plain-bowl", _cylinder(), _cylinder()) is None


def _row(seed, outcome, hidden=None):
    return {"object": "vase", "seed": seed, "outcome": outcome, "evidence_sigma": 1.0 if outcome != "registered" else 30.0,
            "best_pose_right": True, "feature_share": 0.006, "feature_in_both": True, "seconds": 60.0,
            "hidden_turn_deg": hidden}


def test_the_section_states_hidden_turns_and_sessions_from_the_rows():
    from bench.symmetric_bench import section

    rows = [_row(0, "registered"), _row(1, "ambiguous", 170.0)]
    sessions = [
        {"seed": 0, "all_right": True, "wrong": 0, "cpu_s": 200.0, "passes": [],
         "pairs": [{"pair": "1-2", "verified": True, "evidence_sigma": 20.0}]},
        {"seed": 1, "all_right": False, "wrong": 1, "cpu_s": 220.0, "passes": [],
         "pairs": [{"pair": "2-3", "verified": False, "evidence_sigma": 1.2}]},
    ]
    r = {"machine": "m", "pairs_per_object": 2, "condition_pairs": 2, "steps": 200, "rows": rows,
         "sessions": sessions, "vase_seeds_scanned": 2}
    text = "\n".join(section(r))
    assert "in 1 of the 2 pairs meeting the condition" in text
    assert "seed 1: 170 deg, ambiguous" in text
    assert "Of the other 1 pairs 1/1 (100 %) were registered" in text
    assert "all three passes right in 1/2 (50 %) sessions, 1 pass(es) placed wrong" in text
    assert "seed 1: pairs 2-3 not (1.2 sigma), passes not all right" in text
    assert "--sessions" in text
