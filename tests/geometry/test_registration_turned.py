"""Registration of turned objects of the simulated world against the true placements.

Passes come from :func:`mocks.pass_cloud.simulated_pass` (the station's sensor, placements and
0.05 mm range noise).  A right pose is within 0.5 deg and 0.5 mm (largest displacement of the source
points) of the truth, the limits of the scan-processing benchmark; a verified pose must be right.
"""

from __future__ import annotations

import numpy as np
import pytest

from mocks.pass_cloud import simulated_pass
from mocks.world import World
from processing.geometry.registration import pose_difference, register_pair

TOL_DEG, TOL_MM = 0.5, 0.5


def _pair(name: str, seed: int):
    w = World.turned(name)
    a, b = simulated_pass(w, seed, 2), simulated_pass(w, seed, 3)
    return a, b, a.pose @ np.linalg.inv(b.pose)


def test_bare_bowl_is_ambiguous_in_shape_with_the_evidence_in_the_reason():
    a, b, truth = _pair("plain-bowl:bare", 0)
    res = register_pair(b.points, a.points, source_normals=b.normals, target_normals=a.normals,
                        preset="draft", seed=0)
    assert not res.verified
    assert "ambiguous" in res.reason and "sigma of the range noise" in res.reason, res.reason
    assert np.isfinite(res.evidence_sigma) and res.evidence_sigma < 5.0


@pytest.mark.slow
def test_vase_with_its_boss_in_both_passes_registers_by_evidence():
    # seed 0, placements 2 and 3: the boss is measured in both passes; the margin alone (about 2 %)
    # refused this pair, the evidence where the poses differ accepts it
    a, b, truth = _pair("vase", 0)
    res = register_pair(b.points, a.points, source_normals=b.normals, target_normals=a.normals,
                        preset="standard", seed=0)
    rot, disp = pose_difference(res.transform, truth, b.points)
    assert res.verified, res.reason
    assert rot < TOL_DEG and disp < TOL_MM
    assert res.margin < 0.05 and res.evidence_sigma >= 5.0
