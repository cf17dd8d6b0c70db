"""Shading of ray hits: direct light with shadows, sky light, one mirror bounce.

The colour signal of Matsuda et al., eq. (2) and (5), summed over the lights
and lobes of a material::

    L(lambda) = sum_lights sum_lobes w * geometry(i, o) * S(cos_d, lambda)
                * E(lambda) * V * cos_i                                 (direct)
              + sum_non-mirror-lobes albedo(cos_o, lambda) * Lsky_mean(n)  (sky)
              + sum_mirror-lobes w * S(cos_d, lambda) * L(mirrored ray)     (mirror)

with V the shadow-ray visibility and the inverse-square falloff of point
lights.  Two interchangeable colour backends evaluate the spectral part:

* :class:`SpectralBackend` (reference): :func:`processing.materials.lobes.material_brdf`
  over the grid's wavelengths for every sample; colours are spectra
  ``(n, L)``, converted to XYZ at the end;
* :class:`TableBackend` (standard, draft): colours are XYZ, stored
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
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import erfc

from processing.cloth.anisotropic_microfacet import anisotropic_lobe
from processing.errors import InputError
from processing.materials.lobes import Lobe, Material, material_brdf
from processing.spectral.spectra import SpectralGrid
from render.scene import Sky
from render.tables import AngleTable, spectral_factor_table, table_index

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
    "SpectralBackend",
    "TableBackend",
    "ShadingContext",
    "light_samples",
    "shade",
    "ALBEDO_TABLE_SIZE",
    "ALBEDO_GRAZING_COS",
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

#: Nodes over cos_o of the directional-albedo tables of sky light (the albedo is
#: smooth in cos_o; the interpolation error is measured in the tests).  The
#: albedo vanishes at exactly cos_o = 0 by definition but tends to a finite
#: limit, so the first node is evaluated at ``ALBEDO_GRAZING_COS``.
ALBEDO_TABLE_SIZE = 65
ALBEDO_GRAZING_COS = 1e-4


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
    """

    material: Material
    groups: tuple[LobeGroup, ...]
    mirrors: tuple[Lobe, ...]
    sky_lobes: tuple[Lobe, ...]

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
    return MaterialPlan(
        material,
        tuple(LobeGroup(k[0], k[1], k[2], tuple(v), k[3]) for k, v in groups.items()),
        tuple(mirrors),
        tuple(sky),
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


# --------------------------------------------------------------------------- backends
def _albedo_spectra(lobe: Lobe, cos_o: NDArray[np.float64], grid: SpectralGrid) -> NDArray[np.float64]:
    """Directional albedo ``(N, L)`` of one lobe including its weight.

    A Lambert lobe's albedo is its weight times its reflectance at every
    cos_o; other lobes use :func:`processing.materials.albedo.directional_albedo`.
    """
    from processing.materials.albedo import directional_albedo

    if lobe.kind == "lambert" and not getattr(lobe.spectral, "angle_dependent", True):
        s = np.asarray(lobe.spectral.reflectance(np.array([1.0]), grid.wavelengths), dtype=np.float64)
        return np.repeat(lobe.weight * s.reshape(1, grid.size), cos_o.size, axis=0)
    return np.asarray(directional_albedo(lobe, cos_o, grid.wavelengths), dtype=np.float64).reshape(
        cos_o.size, grid.size
    )


class SpectralBackend:
    """Per-sample spectral evaluation; colours are spectral radiance ``(n, L)`` (float64).

    Every method returning a colour takes the per-sample scalar factor
    (irradiance scale, sky scale, lobe weight) and applies it.  Direct light
    and mirror reflections are evaluated at every wavelength for every
    sample; sky light on non-mirror lobes reads the directional albedo
    spectra from a table over cos_o (``ALBEDO_TABLE_SIZE`` nodes, the same
    quadrature as the table path).

    Parameters
    ----------
    grid
        Wavelength grid of the spectra (nm).
    k
        XYZ normalisation of the key light (a white Lambertian facing it
        has Y = 1).
    lights
        The prepared lights.
    sky
        The sky (black: no albedo tables).
    sky_radiance
        Sky radiance spectrum per unit scale, ``(L,)``.
    plans
        One :class:`MaterialPlan` per global material number.
    albedo_size
        Nodes of the directional-albedo tables over cos_o.
    """

    def __init__(
        self,
        grid: SpectralGrid,
        k: float,
        lights: tuple[LightPlan, ...],
        sky: Sky,
        sky_radiance: NDArray[np.float64],
        plans: tuple[MaterialPlan, ...],
        albedo_size: int = ALBEDO_TABLE_SIZE,
    ) -> None:
        self.grid = grid
        self.wavelengths = grid.wavelengths
        self.k = k
        self.lights = lights
        self.sky_radiance = sky_radiance
        self.plans = plans
        self.channels = grid.size
        self.albedo: list[AngleTable | None] = []
        nodes = np.linspace(0.0, 1.0, albedo_size)
        nodes[0] = ALBEDO_GRAZING_COS
        for plan in plans:
            if sky.is_black or not plan.sky_lobes:
                self.albedo.append(None)
                continue
            total = np.zeros((albedo_size, grid.size))
            for lobe in plan.sky_lobes:
                total += _albedo_spectra(lobe, nodes, grid)
            self.albedo.append(AngleTable(total * sky_radiance))

    def zeros(self, n: int) -> NDArray[np.float64]:
        """A black colour array for ``n`` samples.

        Parameters
        ----------
        n
            Number of samples.

        Returns
        -------
        ndarray
            float64 zeros ``(n, L)``.
        """
        return np.zeros((n, self.channels))

    @staticmethod
    def add(out: NDArray[np.float64], idx: NDArray[np.intp] | None, term: NDArray[np.float64]) -> None:
        """``out[idx] += term`` (all rows when ``idx`` is None).

        Parameters
        ----------
        out
            Colours ``(n, L)``, changed in place.
        idx
            Rows to add to, or None for all.
        term
            Colours ``(len(idx), L)``.
        """
        if idx is None:
            out += term
        else:
            out[idx] += term

    def direct(self, mat: int, light: int, ci: Vec, co: Vec, ch: Vec, cd: Vec, scale: Vec,
               tangential: tuple[Vec, Vec, Vec, Vec] | None = None) -> NDArray[np.float64]:
        """Radiance from light ``light``: ``material_brdf * E * cos_i * scale``.

        Parameters
        ----------
        mat
            Global material number.
        light
            Light number.
        ci, co, ch, cd
            cos_i, cos_o, cos_h, cos_d of the samples, ``(n,)``.
        scale
            Irradiance scale (falloff and visibility), ``(n,)``.
        tangential
            Tangent-frame components (i_t, i_b, o_t, o_b) for anisotropic
            lobes.

        Returns
        -------
        ndarray
            float64 spectral radiance ``(n, L)``.
        """
        if tangential is not None:
            tangential = tuple(np.asarray(x, np.float64) for x in tangential)
        f = material_brdf(self.plans[mat].material, ci, co, ch, cd, self.wavelengths, tangential)
        f *= (np.asarray(ci, np.float64) * scale)[:, None]
        f *= self.lights[light].spectrum
        return f

    def has_sky_diffuse(self, mat: int) -> bool:
        """True when material ``mat`` has non-mirror lobes and the sky is not black.

        Parameters
        ----------
        mat
            Global material number.

        Returns
        -------
        bool
            Whether :meth:`sky_diffuse` adds anything.
        """
        return self.albedo[mat] is not None

    def sky_diffuse(self, mat: int, cos_o: Vec, factor: Vec) -> NDArray[np.float64]:
        """Sky light of the non-mirror lobes: albedo(cos_o) * sky spectrum * ``factor``.

        Parameters
        ----------
        mat
            Global material number.
        cos_o
            ``(n,)`` cosines of the view direction.
        factor
            ``(n,)`` mean sky scale over each hemisphere.

        Returns
        -------
        ndarray
            float64 ``(n, L)``.
        """
        out = self.albedo[mat].lookup(cos_o).astype(np.float64)
        out *= np.asarray(factor, np.float64)[:, None]
        return out

    def mirror_factor(self, mat: int, j: int, cos_d: Vec) -> NDArray[np.float64]:
        """Spectral factor ``S(cos_d, lambda)`` of mirror lobe ``j``.

        Parameters
        ----------
        mat
            Global material number.
        j
            Mirror lobe number within the material's plan.
        cos_d
            ``(n,)`` cosines of the half vector with the view direction.

        Returns
        -------
        ndarray
            float64 ``(n, L)``.
        """
        lobe = self.plans[mat].mirrors[j]
        return np.asarray(lobe.spectral.reflectance(np.asarray(cos_d, np.float64), self.wavelengths),
                          dtype=np.float64)

    def mirror_sky(self, mat: int, j: int, cos_d: Vec, factor: Vec) -> NDArray[np.float64]:
        """Sky seen in mirror lobe ``j``: ``S(cos_d) * sky spectrum * factor``.

        Parameters
        ----------
        mat, j, cos_d
            As in :meth:`mirror_factor`.
        factor
            ``(n,)`` sky scale along the mirrored rays times the ray weights.

        Returns
        -------
        ndarray
            float64 ``(n, L)``.
        """
        out = self.mirror_factor(mat, j, cos_d) * self.sky_radiance
        out *= np.asarray(factor, np.float64)[:, None]
        return out

    def from_spectral(self, spectra: NDArray[np.float64]) -> NDArray[np.float64]:
        """Spectra ``(n, L)`` as colours of this backend (the same).

        Parameters
        ----------
        spectra
            ``(n, L)`` spectral radiance.

        Returns
        -------
        ndarray
            ``spectra`` itself.
        """
        return spectra

    def background(self, factor: Vec) -> NDArray[np.float64]:
        """Sky radiance of scale ``factor`` (per sample).

        Parameters
        ----------
        factor
            ``(n,)`` sky scales.

        Returns
        -------
        ndarray
            float64 ``(n, L)``.
        """
        return np.asarray(factor, np.float64)[:, None] * self.sky_radiance

    def to_xyz(self, colour: NDArray[np.float64]) -> NDArray[np.float32]:
        """XYZ of the colours, normalised by ``k``.

        Parameters
        ----------
        colour
            ``(n, L)`` spectral radiance.

        Returns
        -------
        ndarray
            float32 ``(n, 3)``.
        """
        from processing.spectral.display import spectra_to_xyz

        return (self.k * spectra_to_xyz(colour, self.grid)).astype(_F32)


class TableBackend:
    """Colours are XYZ, channel-major ``(3, n)`` float32, from per-(material, light) angular tables.

    Parameters
    ----------
    grid, k, lights, sky, sky_radiance, plans
        As for :class:`SpectralBackend`.
    size
        Nodes of the angular tables over cos_d.
    spectral
        The spectral backend of the same scene, for mirror reflections of
        other objects (formed per wavelength) and the sky's albedo spectra.
    """

    def __init__(
        self,
        grid: SpectralGrid,
        k: float,
        lights: tuple[LightPlan, ...],
        sky: Sky,
        sky_radiance: NDArray[np.float64],
        plans: tuple[MaterialPlan, ...],
        size: int,
        spectral: SpectralBackend,
    ) -> None:
        from processing.spectral.display import spectra_to_xyz

        self.grid = grid
        self.k = k
        self.size = size
        self.plans = plans
        self.channels = 3
        self.spectral = spectral
        # light_tables[mat][light][group]: sum over the group's lobes of weight * table
        self.light_tables: list[list[list[AngleTable]]] = []
        for plan in plans:
            per_light = []
            for light in lights:
                per_group = []
                for group in plan.groups:
                    table = None
                    for weight, factor in group.members:
                        t = spectral_factor_table(factor, light.spectrum, grid, k * weight, size)
                        table = t if table is None else table + t
                    per_group.append(table)
                per_light.append(per_group)
            self.light_tables.append(per_light)
        self.sky_tables: list[AngleTable | None] = []
        self.mirror_tables: list[list[AngleTable]] = []
        for mat, plan in enumerate(plans):
            alb = spectral.albedo[mat]
            self.sky_tables.append(None if alb is None else AngleTable(k * spectra_to_xyz(alb.values, grid)))
            self.mirror_tables.append(
                [spectral_factor_table(lobe.spectral, sky_radiance, grid, k, size) for lobe in plan.mirrors]
            )
        self.background_xyz = (k * spectra_to_xyz(sky_radiance, grid)).astype(_F32)

    def zeros(self, n: int) -> NDArray[np.float32]:
        """A black colour array for ``n`` samples.

        Parameters
        ----------
        n
            Number of samples.

        Returns
        -------
        ndarray
            float32 zeros ``(3, n)``.
        """
        return np.zeros((3, n), dtype=_F32)

    @staticmethod
    def add(out: NDArray[np.float32], idx: NDArray[np.intp] | None, term: NDArray[np.float32]) -> None:
        """``out[:, idx] += term`` (all columns when ``idx`` is None), one channel at a time.

        Parameters
        ----------
        out
            Colours ``(3, n)``, changed in place.
        idx
            Columns to add to, or None for all.
        term
            Colours ``(3, len(idx))``.
        """
        if idx is None:
            out += term
        else:
            for c in range(out.shape[0]):
                row = out[c]
                row[idx] += term[c]

    def direct(self, mat: int, light: int, ci: Vec, co: Vec, ch: Vec, cd: Vec, scale: Vec,
               tangential: tuple[Vec, Vec, Vec, Vec] | None = None) -> NDArray[np.float32]:
        """XYZ from light ``light``: sum over lobe groups of geometry * cos_i * scale * T(cos_d).

        Anisotropic groups (no cut-off: the ellipsoid distribution has long
        tails) use ``tangential`` = (i_t, i_b, o_t, o_b).

        Parameters
        ----------
        mat, light, ci, co, ch, cd, scale, tangential
            As for :meth:`SpectralBackend.direct`.

        Returns
        -------
        ndarray
            float32 XYZ ``(3, n)``.

        Raises
        ------
        ValueError
            An anisotropic lobe without ``tangential``.
        """
        plan = self.plans[mat]
        tables = self.light_tables[mat][light]
        n = len(ci)
        out = self.zeros(n)
        index = None
        for group, table in zip(plan.groups, tables):
            if group.kind == "lambert":
                if index is None:
                    index = table_index(cd, self.size)
                out += table.lookup_channels(index=index) * (scale * (ci * _F32(1.0 / math.pi)))
                continue
            if group.kind == "anisotropic":
                if tangential is None:
                    raise InputError("an anisotropic lobe needs the tangent frame of the hits")
                if index is None:
                    index = table_index(cd, self.size)
                s = anisotropic_lobe(ci, co, ch, cd, *tangential, group.roughness, group.roughness_b)
                s *= ci
                s *= scale
                term = table.lookup_channels(index=index)
                term *= s
                out += term
                continue
            # Only samples whose half vector lies within the lobe: elsewhere D is
            # below exp(-D_CUTOFF) of its peak and the term is skipped.
            c2 = np.maximum(ch * ch, _F32(1e-12))
            within = (c2 - _F32(1.0)) > _F32(-D_CUTOFF * group.roughness ** 2) * c2
            within &= ch > 0
            active = np.flatnonzero(within)
            if active.size == 0:
                continue
            if active.size == n:
                a_ci, a_co, a_ch, a_cd, a_scale, active = ci, co, ch, cd, scale, None
            else:
                a_ci, a_co, a_ch, a_cd, a_scale = (np.take(x, active) for x in (ci, co, ch, cd, scale))
            s = microfacet_geometry(a_ci, a_co, a_ch, a_cd, group.roughness, group.shadowing)
            s *= a_ci
            s *= a_scale
            term = table.lookup_channels(a_cd)
            term *= s
            self.add(out, active, term)
        return out

    def has_sky_diffuse(self, mat: int) -> bool:
        """True when material ``mat`` has non-mirror lobes and the sky is not black.

        Parameters
        ----------
        mat
            Global material number.

        Returns
        -------
        bool
            Whether :meth:`sky_diffuse` adds anything.
        """
        return self.sky_tables[mat] is not None

    def sky_diffuse(self, mat: int, cos_o: Vec, factor: Vec) -> NDArray[np.float32]:
        """Sky light of the non-mirror lobes from the albedo table, times ``factor``.

        Parameters
        ----------
        mat, cos_o, factor
            As for :meth:`SpectralBackend.sky_diffuse`.

        Returns
        -------
        ndarray
            float32 XYZ ``(3, n)``.
        """
        term = self.sky_tables[mat].lookup_channels(cos_o)
        return term * np.asarray(factor, _F32)

    def mirror_factor(self, mat: int, j: int, cos_d: Vec) -> NDArray[np.float64]:
        """Spectral factor of mirror lobe ``j`` (per wavelength, for products with reflected spectra).

        Parameters
        ----------
        mat, j, cos_d
            As for :meth:`SpectralBackend.mirror_factor`.

        Returns
        -------
        ndarray
            float64 ``(n, L)``.
        """
        return self.spectral.mirror_factor(mat, j, cos_d)

    def mirror_sky(self, mat: int, j: int, cos_d: Vec, factor: Vec) -> NDArray[np.float32]:
        """Sky seen in mirror lobe ``j`` from its sky table, times ``factor``.

        Parameters
        ----------
        mat, j, cos_d, factor
            As for :meth:`SpectralBackend.mirror_sky`.

        Returns
        -------
        ndarray
            float32 XYZ ``(3, n)``.
        """
        term = self.mirror_tables[mat][j].lookup_channels(cos_d)
        return term * np.asarray(factor, _F32)

    def from_spectral(self, spectra: NDArray[np.float64]) -> NDArray[np.float32]:
        """XYZ of radiance spectra.

        Parameters
        ----------
        spectra
            ``(n, L)`` spectral radiance.

        Returns
        -------
        ndarray
            float32 ``(3, n)``.
        """
        return np.ascontiguousarray(self.spectral.to_xyz(spectra).T)

    def background(self, factor: Vec) -> NDArray[np.float32]:
        """XYZ of the sky radiance of scale ``factor``.

        Parameters
        ----------
        factor
            ``(n,)`` sky scales.

        Returns
        -------
        ndarray
            float32 ``(3, n)``.
        """
        return self.background_xyz[:, None] * np.asarray(factor, _F32)

    def to_xyz(self, colour: NDArray[np.float32]) -> NDArray[np.float32]:
        """XYZ rows of the colours.

        Parameters
        ----------
        colour
            ``(3, n)`` XYZ.

        Returns
        -------
        ndarray
            ``(n, 3)``, a transposed view.
        """
        return colour.T


# --------------------------------------------------------------------------- context
@dataclass
class ShadingContext:
    """Everything shading needs besides the hits: lights, sky, materials, ray tracer.

    Rays are float32 ``(n, 6)`` rows (origin, direction).

    Attributes
    ----------
    lights
        The prepared lights (the first is the key light).
    sky
        The environment.
    plans
        One :class:`MaterialPlan` per global material number.
    offset
        Distance secondary rays start off the surface (scene units).
    shadows
        Cast shadow rays.
    mirror_bounces
        Mirror bounces (0 or 1).
    mirror_rays
        Jittered rays per rough mirror sample (0: the ideal direction).
    cast
        ``cast(rays)``: Open3D's ``cast_rays`` answer as NumPy arrays.
    occluded
        ``occluded(rays, tfar)``: ``test_occlusions``.
    make_hits
        ``make_hits(rays, answer, rows)``: the hit rows of an answer as
        :class:`Hits`.
    stats
        Counts of shadow rays, mirror rays and secondary hits.
    """

    lights: tuple[LightPlan, ...]
    sky: Sky
    plans: tuple[MaterialPlan, ...]
    offset: float
    shadows: bool
    mirror_bounces: int
    mirror_rays: int
    cast: Callable[[NDArray[np.float32]], dict[str, NDArray]]
    occluded: Callable[[NDArray[np.float32], float], NDArray[np.bool_]]
    make_hits: Callable[[NDArray[np.float32], dict[str, NDArray], NDArray[np.intp]], Hits]
    stats: dict[str, float] = field(default_factory=dict)

    def count(self, key: str, value: float) -> None:
        """Add ``value`` to the count ``key`` of :attr:`stats`.

        Parameters
        ----------
        key
            Name of the count.
        value
            Amount to add.
        """
        self.stats[key] = self.stats.get(key, 0) + value


def _rays(origins: NDArray[np.float32], directions: NDArray[np.float32]) -> NDArray[np.float32]:
    """``(n, 6)`` ray rows from ``(3, n)`` origins and ``(3, n)`` (or one ``(3,)``) directions."""
    n = origins.shape[1]
    rays = np.empty((n, 6), dtype=_F32)
    rays[:, :3] = origins.T
    rays[:, 3:] = directions.T if directions.ndim == 2 else directions
    return rays


def _offset_origins(position: NDArray[np.float32], normal: NDArray[np.float32], directions: NDArray[np.float32],
                    offset: float) -> NDArray[np.float32]:
    """Ray origins pushed off the surface along the geometric ``normal``, to the side ``directions`` leave."""
    side = np.where(dot3(normal, directions) >= 0, _F32(offset), _F32(-offset))
    return position + normal * side


def light_samples(
    ctx: ShadingContext, hits: Hits, index: int
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Direction to light ``index``, cos_i and the irradiance scale per hit.

    Shadow rays start on the light's side of the face, offset along the
    geometric normal; a point light's ray stops just short of it.

    Parameters
    ----------
    ctx
        The shading context (its ``occluded`` casts the shadow rays).
    hits
        The surface samples.
    index
        Light number.

    Returns
    -------
    tuple of ndarray
        ``(l, cos_i, scale)``: ``l`` is ``(3,)`` for a directional light
        and ``(3, m)`` for a point light; ``cos_i`` ``(m,)``; ``scale``
        ``(m,)`` includes the inverse-square falloff and the shadow-ray
        visibility (0 when unlit or shadowed).
    """
    light = ctx.lights[index]
    m = len(hits)
    if light.kind == "directional":
        l = light.vector.astype(_F32)
        cos_i = dot3(l, hits.shading_normal)
        scale = np.ones(m, dtype=_F32)
    else:
        to_light = light.vector.astype(_F32)[:, None] - hits.position
        dist2 = np.maximum(dot3(to_light, to_light), _F32(1e-30))
        inv = _F32(1.0) / np.sqrt(dist2)
        l = to_light * inv
        cos_i = dot3(hits.shading_normal, l)
        scale = inv * inv
    lit = cos_i > 0
    if ctx.shadows:
        rows = np.flatnonzero(lit)
        if rows.size:
            ldir = l if l.ndim == 1 else _take(l, rows)
            origins = _offset_origins(_take(hits.position, rows), _take(hits.geometric_normal, rows), ldir,
                                      ctx.offset)
            if light.kind == "directional":
                blocked = ctx.occluded(_rays(origins, ldir), math.inf)
            else:
                blocked = ctx.occluded(_rays(origins, light.vector.astype(_F32)[:, None] - origins), 1.0 - 1e-4)
            ctx.count("shadow_rays", rows.size)
            lit[rows[blocked]] = False
    scale = np.where(lit, scale, _F32(0.0))
    return l, cos_i, scale


def _reflect(view: NDArray[np.float32], normal: NDArray[np.float32], cos: NDArray[np.float32]) -> NDArray[np.float32]:
    """Mirror ``view`` about ``normal``: ``2 (v . n) n - v``."""
    r = normal * (_F32(2.0) * cos)
    r -= view
    return r


def shade(ctx: ShadingContext, hits: Hits, backend: SpectralBackend | TableBackend, depth: int,
          rng: np.random.Generator) -> NDArray:
    """Outgoing radiance toward ``hits.view`` in the backend's colour layout.

    Parameters
    ----------
    ctx
        Lights, sky, materials and the ray tracer.
    hits
        The surface samples.
    backend
        :class:`SpectralBackend` (returns ``(m, L)`` spectra) or
        :class:`TableBackend` (returns ``(3, m)`` XYZ).
    depth
        Mirror bounces left (0: mirror lobes see the unoccluded sky).
    rng
        Generator for the rough-mirror jitter.

    Returns
    -------
    ndarray
        The radiance of every hit: spectra ``(m, L)`` or XYZ ``(3, m)``.

    Raises
    ------
    ValueError
        An anisotropic material whose hits carry no tangents.
    """
    m = len(hits)
    out = backend.zeros(m)
    if m == 0:
        return out
    per_light = [light_samples(ctx, hits, i) for i in range(len(ctx.lights))]
    if len(ctx.plans) > 1:
        materials = np.flatnonzero(np.bincount(hits.material, minlength=len(ctx.plans)))
    else:
        materials = np.zeros(1, dtype=np.int32)
    for mat in materials:
        mat = int(mat)
        plan = ctx.plans[mat]
        in_mat = (hits.material == mat) if materials.size > 1 else None
        # ---- direct light
        for li, (l, cos_i, scale) in enumerate(per_light):
            on = scale > 0
            if in_mat is not None:
                on &= in_mat
            idx = np.flatnonzero(on)
            if idx.size == 0:
                continue
            if idx.size == m:
                idx = None
            v = _take(hits.view, idx)
            ns = _take(hits.shading_normal, idx)
            ld = l if l.ndim == 1 else _take(l, idx)
            h = v + (ld[:, None] if ld.ndim == 1 else ld)
            _normalise(h)
            ch = dot3(ns, h)
            cd = np.clip(dot3(v, h), _F32(0.0), _F32(1.0))
            tangential = None
            if plan.anisotropic:
                if hits.tangent is None:
                    raise InputError(f"material {plan.material.name!r} is anisotropic but the hits carry no tangents")
                t = _take(hits.tangent, idx)
                b = cross3(ns, t)
                tangential = (dot3(t, ld), dot3(b, ld), dot3(t, v), dot3(b, v))
            term = backend.direct(mat, li, _take(cos_i, idx), _take(hits.cos_o, idx), ch, cd, _take(scale, idx),
                                  tangential)
            backend.add(out, idx, term)
        sel = None if in_mat is None else np.flatnonzero(in_mat)
        # ---- sky light through the albedo of non-mirror lobes
        if not ctx.sky.is_black and backend.has_sky_diffuse(mat):
            mean = ctx.sky.hemisphere_mean(_take(hits.shading_normal, sel).T).astype(_F32)
            backend.add(out, sel, backend.sky_diffuse(mat, _take(hits.cos_o, sel), mean))
        # ---- mirror lobes
        for j, lobe in enumerate(plan.mirrors):
            _mirror(ctx, hits if sel is None else hits.take(sel), sel, out, backend, mat, j, lobe, depth, rng)
    return out


def _mirror(ctx: ShadingContext, sub: Hits, sel: NDArray[np.intp] | None, out: NDArray,
            backend: SpectralBackend | TableBackend, mat: int, j: int, lobe: Lobe, depth: int,
            rng: np.random.Generator) -> None:
    """Add mirror lobe ``j`` of material ``mat`` for the hits ``sub`` (rows ``sel`` of ``out``)."""
    co = sub.cos_o
    weight = _F32(lobe.weight)
    if depth <= 0:
        if ctx.sky.is_black:
            return
        r = _reflect(sub.view, sub.shading_normal, co)
        factor = ctx.sky.radiance_scale(r.T).astype(_F32) * weight
        backend.add(out, sel, backend.mirror_sky(mat, j, co, factor))
        return
    n_rays = ctx.mirror_rays if ctx.mirror_rays > 0 else 1
    for _ in range(n_rays):
        if ctx.mirror_rays > 0:
            h = sample_beckmann_normals(sub.shading_normal, lobe.roughness, rng)
            cd = dot3(sub.view, h)
            r = _reflect(sub.view, h, cd)
            ci = dot3(sub.shading_normal, r)
            ch = dot3(sub.shading_normal, h)
            ok = (ci > 0) & (cd > 0)
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                w = _mirror_g(lobe, ci, co, ch, cd) * cd / (co * ch)
            w = np.where(ok, w, _F32(0.0)) * (weight / _F32(n_rays))
            rows = np.flatnonzero(w > 0)
        else:
            cd = co
            r = _reflect(sub.view, sub.shading_normal, co)
            w = np.full(len(sub), weight, dtype=_F32)
            rows = np.arange(len(sub))
        if rows.size == 0:
            continue
        all_rows = rows.size == len(sub)
        key = None if all_rows else rows
        r_rows = _take(r, key)
        origins = _offset_origins(_take(sub.position, key), _take(sub.geometric_normal, key), r_rows, ctx.offset)
        rays = _rays(origins, r_rows)
        answer = ctx.cast(rays)
        ctx.count("mirror_rays", rows.size)
        hit = np.isfinite(answer["t_hit"])
        target = rows if sel is None else sel[rows]
        cd_rows = _take(cd, key)
        w_rows = _take(w, key)
        if not ctx.sky.is_black:
            miss = np.flatnonzero(~hit)
            if miss.size:
                factor = ctx.sky.radiance_scale(np.take(r_rows, miss, axis=1).T).astype(_F32)
                factor *= np.take(w_rows, miss)
                idx = None if (sel is None and miss.size == len(sub)) else target[miss]
                backend.add(out, idx, backend.mirror_sky(mat, j, np.take(cd_rows, miss), factor))
        hit_rows = np.flatnonzero(hit)
        if hit_rows.size:
            second = ctx.make_hits(rays, answer, hit_rows)
            ctx.count("secondary_hits", hit_rows.size)
            spectral = backend.spectral if isinstance(backend, TableBackend) else backend
            radiance = shade(ctx, second, spectral, depth - 1, rng)
            product = backend.mirror_factor(mat, j, np.take(cd_rows, hit_rows))
            product *= radiance
            product *= np.take(w_rows, hit_rows).astype(np.float64)[:, None]
            backend.add(out, target[hit_rows], backend.from_spectral(product))
