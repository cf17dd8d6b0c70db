"""The shading's geometry: ray hits, microfacet terms, material and light plans.

The integrator (:mod:`render.integrator`) and the colour backends
(:mod:`render.backends`) build on these.  What they compute together is the
colour signal of Matsuda et al., eq. (2) and (5), summed over the lights
and lobes of a material::

    L(lambda) = sum_lights sum_lobes w * geometry(i, o) * S(cos_d, lambda)
                * E(lambda) * V * cos_i                                 (direct)
              + sum_non-mirror-lobes albedo(cos_o, lambda) * Lsky_mean(n)  (sky)
              + sum_mirror-lobes w * S(cos_d, lambda) * L(mirrored ray)     (mirror)

with V the shadow-ray visibility and the inverse-square falloff of point
lights.  Two interchangeable colour backends evaluate the spectral part:

* :class:`render.backends.SpectralBackend` (reference): :func:`processing.materials.lobes.material_brdf`
  over the grid's wavelengths for every sample; colours are spectra
  ``(n, L)``, converted to XYZ at the end;
* :class:`render.backends.TableBackend` (standard, draft): colours are XYZ, stored
  channel-major ``(3, n)``, read from the angular tables of
  :mod:`render.tables`, which hold the same spectral integral precomputed per
  (lobe, light).  Microfacet terms are evaluated only where the half vector
  lies inside the lobe (elsewhere D is below ``exp(-D_CUTOFF)`` of its peak).

The geometry (positions, interpolated normals, visibility, mirrored rays) is
computed once per sample and shared by all lobes and both backends.  Vectors
are stored as ``(3, m)`` float32 arrays (one contiguous row per coordinate),
which keeps dot products and gathers cheap.

Approximations (stated, and measured in the tests):

* **Sky light on non-mirror lobes.**  Each lobe's directional albedo
  ``A(cos_o, lambda)`` times the cosine-weighted mean sky radiance over the
  hemisphere of the shading normal, ignoring occlusion of the sky by the
  scene (no ambient occlusion) and the lobe's angular shape within the
  gradient.  Exact for a uniform sky on an unoccluded surface.
* **Mirror lobes** reflect the environment along the mirrored view ray
  (the ideal direction, or, with ``mirror_rays > 0``, directions sampled from
  the lobe's Beckmann distribution with weight ``G cos_d / (cos_o cos_h)``,
  the unbiased estimator for D cos_h sampling).  With one bounce the ray is
  traced: an object it hits is shaded with its direct light and sky light
  (its own mirror lobes see the unoccluded sky); a miss sees the sky.  With
  no bounce the mirrored direction sees the unoccluded sky.  In the table
  path the product of the mirror's spectral factor and the reflected
  object's spectrum is formed per wavelength for those rays.
* **Lights** are points and directions (no area lights), so they are not
  seen in mirrors except through the mirror lobe's own (narrow) D term.

docs/rendering.md ("Sky light approximation") says the same for users.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of
a craft object based on a light reflection model", IPSJ technical report
(no DOI).
Cook, R. L., Torrance, K. E. (1982), "A reflectance model for computer
graphics", ACM TOG 1(1), 7-24, doi:10.1145/357290.357293.
Walter, B., Marschner, S. R., Li, H., Torrance, K. E. (2007), "Microfacet
models for refraction through rough surfaces", EGSR 2007, 195-206,
doi:10.2312/EGWR/EGSR07/195-206.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import erfc

from processing.errors import InputError
from processing.materials.lobes import Lobe, Material

__all__ = [
    "Hits",
    "LobeGroup",
    "MaterialPlan",
    "LightPlan",
    "plan_material",
    "dot3",
    "cross3",
    "microfacet_geometry",
    "smith_g1",
    "sample_beckmann_normals",
    "orthonormal_basis",
    "D_CUTOFF",
]

_F32 = np.float32
Vec = NDArray[np.float32]
_SQRT_PI = math.sqrt(math.pi)

#: Microfacet terms whose Beckmann exponent tan^2(theta_h) / sigma^2 exceeds
#: this (D below exp(-30) = 1e-13 of its peak) are skipped in the table path.
D_CUTOFF = 30.0

#: Smith masking is 1 to float32 precision (1 - G1 < 1e-8) for
#: a = cot(theta) / sigma above this; only smaller a are evaluated.
_G1_ONE_ABOVE = 4.0



# --------------------------------------------------------------------------- vector helpers
def dot3(a: NDArray[np.float32], b: NDArray[np.float32]) -> NDArray[np.float32]:
    """Dot products of ``(3, m)`` vector arrays (either may be one ``(3,)`` vector).

    Parameters
    ----------
    a, b
        ``(3, m)`` or ``(3,)`` arrays.

    Returns
    -------
    ndarray
        ``(m,)`` (a 0-d array when both are single vectors).

    Examples
    --------
    >>> dot3(np.array([[1.0, 0.0], [0.0, 2.0], [0.0, 0.0]]), np.array([1.0, 1.0, 0.0])).tolist()
    [1.0, 2.0]
    """
    if a.ndim == 1 and b.ndim == 1:
        return np.asarray(a @ b)
    if a.ndim == 1:
        return a.astype(b.dtype, copy=False) @ b
    if b.ndim == 1:
        return b.astype(a.dtype, copy=False) @ a
    out = a[0] * b[0]
    out += a[1] * b[1]
    out += a[2] * b[2]
    return out


def cross3(a: NDArray[np.float32], b: NDArray[np.float32]) -> NDArray[np.float32]:
    """Cross products of ``(3, m)`` vector arrays.

    Parameters
    ----------
    a, b
        ``(3, m)`` arrays.

    Returns
    -------
    ndarray
        ``(3, m)``, ``a x b``.

    Examples
    --------
    >>> cross3(np.array([[0.0], [0.0], [1.0]]), np.array([[1.0], [0.0], [0.0]])).ravel().tolist()
    [0.0, 1.0, 0.0]
    """
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _normalise(v: NDArray[np.float32]) -> NDArray[np.float32]:
    v *= _F32(1.0) / np.sqrt(dot3(v, v))
    return v


def _take(a: NDArray, idx: NDArray[np.intp] | None) -> NDArray:
    """Columns ``idx`` of a ``(3, m)`` array or entries of an ``(m,)`` array (all when None)."""
    if idx is None:
        return a
    return np.take(a, idx, axis=a.ndim - 1)


# --------------------------------------------------------------------------- geometry per hit
@dataclass(eq=False)
class Hits:
    """Surface geometry of ray hits, float32; vectors are ``(3, m)``.

    Attributes
    ----------
    position
        ``(3, m)`` hit points.
    shading_normal
        ``(3, m)`` unit normals interpolated from the vertex normals with the
        barycentric weights, on the viewer's side.
    geometric_normal
        ``(3, m)`` unit face normals, on the viewer's side.
    view
        ``(3, m)`` unit directions from the hit toward the ray origin.
    cos_o
        ``(m,)`` shading normal . view, > 0.
    material
        ``(m,)`` global material number.
    tangent
        ``(3, m)`` unit yarn directions orthogonal to the shading normal
        (only when the scene has anisotropic materials, else None).
    """

    position: NDArray[np.float32]
    shading_normal: NDArray[np.float32]
    geometric_normal: NDArray[np.float32]
    view: NDArray[np.float32]
    cos_o: NDArray[np.float32]
    material: NDArray[np.int32]
    tangent: NDArray[np.float32] | None = None

    def __len__(self) -> int:
        return int(self.cos_o.shape[0])

    def take(self, idx: NDArray[np.intp]) -> Hits:
        """The subset of hits ``idx``.

        Parameters
        ----------
        idx
            Indices of the hits to keep.

        Returns
        -------
        Hits
            Copies of those columns.
        """
        return Hits(
            _take(self.position, idx), _take(self.shading_normal, idx), _take(self.geometric_normal, idx),
            _take(self.view, idx), _take(self.cos_o, idx), _take(self.material, idx),
            None if self.tangent is None else _take(self.tangent, idx),
        )


# --------------------------------------------------------------------------- microfacet terms
def smith_g1(cos_v: NDArray[np.float32], roughness: float) -> NDArray[np.float32]:
    """Smith masking of the Beckmann distribution, float32.

    The same function as :func:`processing.materials.microfacet.smith_g1_beckmann`
    (Walter et al. 2007, eq. (27)), written with ``erfc`` so the large-``a``
    end needs no cancellation: ``Lambda = (exp(-a^2)/(a sqrt(pi)) - erfc(a)) / 2``
    with ``a = cot(theta) / sigma``; it is evaluated only where
    ``a < 4`` (elsewhere 1 - G1 < 1e-8).

    Parameters
    ----------
    cos_v
        Cosines of the direction with the surface normal (clipped to [0, 1]).
    roughness
        Beckmann roughness sigma (RMS slope).

    Returns
    -------
    ndarray
        float32, the shape of ``cos_v``: masking in [0, 1].

    References
    ----------
    Smith, B. (1967), "Geometrical shadowing of a random rough surface",
    IEEE Trans. Antennas Propag. 15(5), 668-671, doi:10.1109/TAP.1967.1138991.
    Walter, B. et al. (2007), doi:10.2312/EGWR/EGSR07/195-206.

    Examples
    --------
    >>> smith_g1(np.array([1.0, 0.0], dtype=np.float32), 0.3).tolist()
    [1.0, 0.0]
    """
    c = np.clip(np.asarray(cos_v, dtype=_F32), _F32(0.0), _F32(1.0))
    s = np.sqrt(np.maximum(_F32(1.0) - c * c, _F32(0.0)))
    # a < A  <=>  c < A sigma s
    rows = np.flatnonzero(c < _F32(_G1_ONE_ABOVE * roughness) * s)
    g = np.ones_like(c)
    if rows.size:
        cr = c[rows]
        with np.errstate(divide="ignore", over="ignore", under="ignore", invalid="ignore"):
            a = cr / (_F32(roughness) * s[rows])
            lam = _F32(0.5) * (np.exp(-a * a) / (a * _F32(_SQRT_PI)) - erfc(a).astype(_F32))
            gr = _F32(1.0) / (_F32(1.0) + lam)
        g[rows] = np.where(cr > 0, np.nan_to_num(gr, nan=0.0, posinf=0.0), _F32(0.0))
    return g


def microfacet_geometry(
    cos_i: NDArray[np.float32],
    cos_o: NDArray[np.float32],
    cos_h: NDArray[np.float32],
    cos_d: NDArray[np.float32],
    roughness: float,
    shadowing: str = "smith",
) -> NDArray[np.float32]:
    """``D G / (4 cos_i cos_o)`` of a Beckmann lobe in 1/sr, float32.

    The float32 counterpart of :func:`processing.materials.microfacet.microfacet_lobe`
    used by the table path.  Zero where either cosine is <= 0.

    Parameters
    ----------
    cos_i, cos_o
        Cosines of the light and view directions with the normal.
    cos_h
        Cosine of the half vector with the normal.
    cos_d
        Cosine of the half vector with the light (or view) direction.
    roughness
        Beckmann roughness sigma.
    shadowing
        ``"smith"``, ``"torrance-sparrow"`` (``"v-cavity"``) or ``"none"``.

    Returns
    -------
    ndarray
        float32, the shape of the cosines, in 1/sr.

    Raises
    ------
    ValueError
        An unknown ``shadowing``.

    References
    ----------
    Cook, R. L., Torrance, K. E. (1982), doi:10.1145/357290.357293.
    Torrance, K. E., Sparrow, E. M. (1967), "Theory for off-specular
    reflection from roughened surfaces", JOSA 57(9), 1105-1114,
    doi:10.1364/JOSA.57.001105.
    Walter, B. et al. (2007), doi:10.2312/EGWR/EGSR07/195-206.

    Examples
    --------
    >>> one = np.ones(1, dtype=np.float32)
    >>> round(float(microfacet_geometry(one, one, one, one, 0.5)[0] * 4), 4)   # D(1) = 1/(pi s^2)
    1.2732
    """
    s2 = _F32(roughness * roughness)
    c2 = np.maximum(cos_h * cos_h, _F32(1e-12))
    with np.errstate(over="ignore", under="ignore"):
        d = np.exp((_F32(1.0) - _F32(1.0) / c2) / s2) / (_F32(math.pi) * s2 * c2 * c2)
    d = np.where(cos_h > 0, d, _F32(0.0))
    if shadowing == "smith":
        g = smith_g1(cos_i, roughness) * smith_g1(cos_o, roughness)
    elif shadowing in ("torrance-sparrow", "v-cavity"):
        cd = np.maximum(cos_d, _F32(1e-12))
        ch = np.clip(cos_h, _F32(0.0), _F32(1.0))
        lo = np.minimum(np.clip(cos_o, _F32(0), _F32(1)), np.clip(cos_i, _F32(0), _F32(1)))
        g = np.minimum(_F32(1.0), _F32(2.0) * ch * lo / cd)
    elif shadowing == "none":
        g = _F32(1.0)
    else:
        raise InputError(f"shadowing={shadowing!r} is not known; use 'smith', 'torrance-sparrow' or 'none'")
    valid = (cos_i > 0) & (cos_o > 0)
    denom = _F32(4.0) * np.where(valid, cos_i * cos_o, _F32(1.0))
    with np.errstate(over="ignore", invalid="ignore"):
        out = d * g / denom
    return np.where(valid, np.nan_to_num(out, nan=0.0, posinf=0.0), _F32(0.0)).astype(_F32, copy=False)


def _mirror_g(lobe: Lobe, ci: NDArray[np.float32], co: NDArray[np.float32], ch: NDArray[np.float32],
              cd: NDArray[np.float32]) -> NDArray[np.float32]:
    if lobe.shadowing == "smith":
        return smith_g1(ci, lobe.roughness) * smith_g1(co, lobe.roughness)
    if lobe.shadowing in ("torrance-sparrow", "v-cavity"):
        lo = np.minimum(co, np.maximum(ci, _F32(0.0)))
        return np.minimum(_F32(1.0), _F32(2.0) * ch * lo / np.maximum(cd, _F32(1e-12)))
    return np.ones_like(ci)


def orthonormal_basis(n: NDArray[np.float32]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Two unit tangents completing unit normals ``n`` (3, m) to right-handed frames.

    Branchless construction of Duff et al. (2017).

    Parameters
    ----------
    n
        ``(3, m)`` unit normals.

    Returns
    -------
    tuple of ndarray
        ``(t, b)``, two ``(3, m)`` unit vectors with ``(t, b, n)``
        right-handed and orthonormal.

    References
    ----------
    Duff, T., Burgess, J., Christensen, P., Hery, C., Kensler, A., Liani, M.,
    Villemin, R. (2017), "Building an orthonormal basis, revisited", Journal
    of Computer Graphics Techniques 6(1), 1-8 (the journal has no DOIs).

    Examples
    --------
    >>> t, b = orthonormal_basis(np.array([[0], [0], [1]], dtype=np.float32))
    >>> (t.ravel() + 0.0).tolist(), (b.ravel() + 0.0).tolist()
    ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    """
    x, y, z = n[0], n[1], n[2]
    sign = np.where(z >= 0, _F32(1.0), _F32(-1.0))
    a = _F32(-1.0) / (sign + z)
    b = x * y * a
    t = np.stack([_F32(1.0) + sign * x * x * a, sign * b, -sign * x])
    u = np.stack([b, sign + y * y * a, -y])
    return t, u


def sample_beckmann_normals(
    normals: NDArray[np.float32], roughness: float, rng: np.random.Generator
) -> NDArray[np.float32]:
    """Microfacet normals ``(3, m)`` drawn with density ``D(h) cos(theta_h)`` around ``normals``.

    Beckmann: ``tan^2 theta_h = -sigma^2 ln(1 - u1)``, ``phi = 2 pi u2``
    (Walter et al. 2007, eq. (28)).

    Parameters
    ----------
    normals
        ``(3, m)`` unit normals.
    roughness
        Beckmann roughness sigma.
    rng
        Generator of the two uniform numbers per normal.

    Returns
    -------
    ndarray
        float32 ``(3, m)`` unit microfacet normals.

    References
    ----------
    Walter, B. et al. (2007), doi:10.2312/EGWR/EGSR07/195-206.

    Examples
    --------
    >>> n = np.repeat(np.array([[0.0], [0.0], [1.0]], dtype=np.float32), 4, axis=1)
    >>> h = sample_beckmann_normals(n, 0.01, np.random.default_rng(1))
    >>> bool(np.all(h[2] > 0.999))
    True
    """
    m = normals.shape[1]
    u = rng.random((2, m), dtype=_F32)
    tan2 = _F32(-roughness * roughness) * np.log1p(-u[0])
    cos_t = _F32(1.0) / np.sqrt(_F32(1.0) + tan2)
    sin_t = np.sqrt(np.maximum(_F32(1.0) - cos_t * cos_t, _F32(0.0)))
    phi = _F32(2.0 * math.pi) * u[1]
    t, b = orthonormal_basis(normals)
    h = t * (sin_t * np.cos(phi))
    h += b * (sin_t * np.sin(phi))
    h += normals * cos_t
    return _normalise(h)


# --------------------------------------------------------------------------- plans
@dataclass(frozen=True)
class LobeGroup:
    """Lobes sharing one geometric factor (kind, roughness(es), shadowing); their spectral factors add.

    Attributes
    ----------
    kind
        ``"lambert"``, ``"microfacet"`` or ``"anisotropic"``.
    roughness
        Beckmann roughness sigma (0 for Lambert; for an anisotropic group
        the ellipsoid's semi-axis along the yarn).
    shadowing
        The microfacet shadowing term (``""`` for Lambert).
    members
        ``(weight, spectral factor)`` of each lobe of the group.
    roughness_b
        The ellipsoid's semi-axis across the yarn (anisotropic groups).
    """

    kind: str
    roughness: float
    shadowing: str
    members: tuple[tuple[float, Any], ...]      # (weight, SpectralFactor)
    roughness_b: float = 0.0


@dataclass(frozen=True)
class MaterialPlan:
    """What a material needs: lobe groups for the lights, mirror lobes, sky-lit lobes.

    Attributes
    ----------
    material
        The material.
    groups
        Its lobes grouped by geometric factor (direct light).
    mirrors
        Its mirror lobes (reflect the environment).
    sky_lobes
        Its other lobes (lit by the sky through their albedo).
    sky_groups
        The other lobes grouped by geometric factor (an environment map
        lights them through their BRDF).
    """

    material: Material
    groups: tuple[LobeGroup, ...]
    mirrors: tuple[Lobe, ...]
    sky_lobes: tuple[Lobe, ...]
    sky_groups: tuple[LobeGroup, ...] = ()

    @property
    def anisotropic(self) -> bool:
        """True when a lobe group needs the tangent frame."""
        return any(g.kind == "anisotropic" for g in self.groups)


def plan_material(material: Material) -> MaterialPlan:
    """Group a material's lobes (zero weights dropped).

    Mirror lobes (``mirror=True`` microfacet lobes) take part in the direct
    light through their D term and reflect the environment; the other lobes
    get sky light through their albedo.  A Lambert lobe flagged ``mirror``
    is treated as a plain Lambert lobe.

    Parameters
    ----------
    material
        The material.

    Returns
    -------
    MaterialPlan
        Its lobe groups, mirror lobes and sky-lit lobes.
    """
    groups: dict[tuple[str, float, str, float], list[tuple[float, Any]]] = {}
    sky_groups: dict[tuple[str, float, str, float], list[tuple[float, Any]]] = {}
    mirrors: list[Lobe] = []
    sky: list[Lobe] = []
    for lobe in material.lobes:
        if lobe.weight <= 0.0:
            continue
        if lobe.kind == "lambert":
            key = ("lambert", 0.0, "", 0.0)
        elif lobe.kind == "anisotropic":
            key = ("anisotropic", float(lobe.roughness), "smith", float(lobe.roughness_b))
        else:
            key = ("microfacet", float(lobe.roughness), lobe.shadowing, 0.0)
        groups.setdefault(key, []).append((float(lobe.weight), lobe.spectral))
        if lobe.mirror and lobe.kind == "microfacet":
            mirrors.append(lobe)
        else:
            sky.append(lobe)
            sky_groups.setdefault(key, []).append((float(lobe.weight), lobe.spectral))
    return MaterialPlan(
        material,
        tuple(LobeGroup(k[0], k[1], k[2], tuple(v), k[3]) for k, v in groups.items()),
        tuple(mirrors),
        tuple(sky),
        tuple(LobeGroup(k[0], k[1], k[2], tuple(v), k[3]) for k, v in sky_groups.items()),
    )


@dataclass(frozen=True)
class LightPlan:
    """A light prepared for shading.

    Attributes
    ----------
    kind
        ``"directional"`` or ``"point"``.
    vector
        ``(3,)`` unit direction toward the light, or its position.
    spectrum
        ``E(lambda)`` on the grid times the light's intensity relative to
        the key light's normalising irradiance, ``(L,)``.
    """

    kind: str
    vector: NDArray[np.float64]
    spectrum: NDArray[np.float64]
