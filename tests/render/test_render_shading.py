"""Float32 shading terms against processing's float64 reference formulas, Beckmann
sampling statistics, frames, lobe grouping."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from processing.materials.lobes import Lobe, Material
from processing.materials.microfacet import microfacet_lobe, smith_g1_beckmann
from render.shading import (
    dot3,
    microfacet_geometry,
    orthonormal_basis,
    plan_material,
    sample_beckmann_normals,
    smith_g1,
)

cosines = st.one_of(st.sampled_from([0.0, 1e-7, 1e-3, 0.5, 1.0 - 1e-7, 1.0]), st.floats(0.0, 1.0))
roughness = st.one_of(st.sampled_from([1e-3, 0.01, 1.0]), st.floats(1e-3, 1.0))


@hsettings(max_examples=200, deadline=None)
@given(c=cosines, s=roughness)
def test_smith_g1_matches_the_float64_reference(c, s):
    got = float(smith_g1(np.array([c], np.float32), s)[0])
    want = float(smith_g1_beckmann(np.float32(c), s))
    assert 0.0 <= got <= 1.0
    assert got == pytest.approx(want, abs=2e-6)


def _half_vector_cosines(ci, co, phi):
    """cos_h and cos_d of the half vector for incidence/view cosines and azimuth difference phi."""
    si, so = math.sqrt(1 - ci * ci), math.sqrt(1 - co * co)
    i = np.array([si, 0.0, ci])
    o = np.array([so * math.cos(phi), so * math.sin(phi), co])
    h = i + o
    h /= np.linalg.norm(h)
    return float(h[2]), float(i @ h)


@hsettings(max_examples=300, deadline=None)
@given(ci=st.floats(1e-4, 1.0), co=st.floats(1e-4, 1.0), phi=st.floats(0.0, math.pi), s=roughness,
       shadowing=st.sampled_from(["smith", "torrance-sparrow", "none"]))
def test_float32_microfacet_geometry_matches_processing(ci, co, phi, s, shadowing):
    ch, cd = _half_vector_cosines(ci, co, phi)
    want = float(microfacet_lobe(ci, co, ch, cd, s, shadowing))
    args = [np.array([x], np.float32) for x in (ci, co, ch, cd)]
    got = float(microfacet_geometry(*args, s, shadowing)[0])
    assert np.isfinite(got) and got >= 0.0
    # float32 cos_h (relative rounding 6e-8) moves the exponent (1 - 1/c^2)/s^2 by
    # 2 * 6e-8 / (c^2 s^2): D inherits that relative error
    rtol = 2e-4 + 3e-7 / (max(ch, 1e-6) ** 2 * s * s)
    assert got == pytest.approx(want, rel=rtol, abs=1e-30)


def test_microfacet_geometry_is_zero_below_the_horizon_and_at_grazing():
    z = np.zeros(3, np.float32)
    c = np.array([0.5, 1.0, 1e-3], np.float32)
    assert np.all(microfacet_geometry(z, c, c, c, 0.3) == 0)
    assert np.all(microfacet_geometry(c, -c, c, c, 0.3) == 0)
    assert np.all(microfacet_geometry(c, c, -c, c, 0.3) == 0)
    with pytest.raises(ValueError, match="shadowing"):
        microfacet_geometry(c, c, c, c, 0.3, "ggx")


@pytest.mark.parametrize("sigma", [0.01, 0.2, 1.0])
def test_beckmann_samples_follow_d_cos(sigma):
    """With density D(h) cos(theta_h), tan^2(theta_h) / sigma^2 is exponential with mean 1
    and the azimuth is uniform (Walter et al. 2007, eq. (28))."""
    rng = np.random.default_rng(11)
    n = 200_000
    normal = np.repeat(np.array([[0.0], [0.0], [1.0]], np.float32), n, axis=1)
    h = sample_beckmann_normals(normal, sigma, rng).astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(h, axis=0), 1.0, atol=1e-6)
    x = (1.0 - h[2] ** 2) / h[2] ** 2 / sigma**2
    assert x.mean() == pytest.approx(1.0, rel=0.01)
    assert np.mean(x > 2.0) == pytest.approx(math.exp(-2.0), abs=0.005)
    phi = np.arctan2(h[1], h[0])
    counts = np.histogram(phi, bins=8, range=(-math.pi, math.pi))[0]
    assert counts.min() > 0.95 * n / 8 and counts.max() < 1.05 * n / 8


def test_beckmann_samples_around_a_tilted_normal_are_centred_on_it():
    rng = np.random.default_rng(5)
    normal = np.array([0.3, -0.5, 0.812404], np.float32)
    normal /= np.linalg.norm(normal)
    h = sample_beckmann_normals(np.repeat(normal[:, None], 50_000, axis=1), 0.1, rng)
    mean = h.mean(axis=1)
    np.testing.assert_allclose(mean / np.linalg.norm(mean), normal, atol=2e-3)


@hsettings(max_examples=100, deadline=None)
@given(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 1e-3)
       | st.sampled_from([(0.0, 0.0, -1.0), (0.0, 0.0, 1.0), (1e-7, 0.0, -1.0)]))
def test_orthonormal_basis_is_orthonormal_even_at_the_south_pole(v):
    n = (np.asarray(v, np.float64) / np.linalg.norm(v)).astype(np.float32)[:, None]
    t, b = orthonormal_basis(n)
    frame = np.stack([t[:, 0], b[:, 0], n[:, 0]]).astype(np.float64)
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=2e-6)
    assert np.linalg.det(frame) == pytest.approx(1.0, abs=1e-5)


def test_dot3_shapes():
    a = np.arange(6, dtype=np.float32).reshape(3, 2)
    v = np.array([1.0, 0.0, 2.0], np.float32)
    np.testing.assert_array_equal(dot3(a, a), [0 + 4 + 16, 1 + 9 + 25])
    np.testing.assert_array_equal(dot3(v, a), [8, 11])
    np.testing.assert_array_equal(dot3(a, v), [8, 11])


class Grey:
    angle_dependent = False

    def reflectance(self, cos_d, wavelengths):
        return np.full(np.shape(cos_d) + (len(wavelengths),), 0.5)


def test_lobes_sharing_a_geometry_are_grouped_and_zero_weights_dropped():
    g = Grey()
    m = Material("mix", (
        Lobe("lambert", 0.3, g),
        Lobe("lambert", 0.2, g),
        Lobe("microfacet", 0.1, g, 0.2),
        Lobe("microfacet", 0.1, g, 0.2, mirror=True),
        Lobe("microfacet", 0.0, g, 0.5),
        Lobe("microfacet", 0.2, g, 0.2, "torrance-sparrow"),
        Lobe("lambert", 0.1, g, mirror=True),
    ))
    plan = plan_material(m)
    kinds = sorted((grp.kind, grp.roughness, grp.shadowing, len(grp.members)) for grp in plan.groups)
    assert kinds == [("lambert", 0.0, "", 3), ("microfacet", 0.2, "smith", 2), ("microfacet", 0.2, "torrance-sparrow", 1)]
    assert [lobe.weight for lobe in plan.mirrors] == [0.1]
    assert len(plan.sky_lobes) == 5            # every non-mirror lobe, the mirror-flagged Lambert included
