"""The two colour backends of the shading: full spectra, or XYZ angle tables.

* :class:`SpectralBackend` (the ``reference`` preset):
  :func:`processing.materials.lobes.material_brdf` over the grid's wavelengths
  for every sample; colours are spectra ``(n, L)``, converted to XYZ at the end;
* :class:`TableBackend` (``standard``, ``draft``): colours are XYZ, stored
  channel-major ``(3, n)``, read from the angular tables of
  :mod:`render.tables`, which hold the same spectral integral precomputed per
  (lobe, light).

Both answer the same questions (direct light of a lobe, sky light through a
lobe's albedo, a mirror lobe's factor), so :func:`render.integrator.shade`
uses either; docs/rendering.md gives their measured agreement.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from processing.cloth.anisotropic_microfacet import anisotropic_lobe
from processing.errors import InputError
from processing.materials.lobes import Lobe, Material, material_brdf
from processing.spectral.spectra import SpectralGrid
from render.environment import EnvironmentPlan
from render.scene import Sky
from render.shading import (
    _F32,
    D_CUTOFF,
    LightPlan,
    MaterialPlan,
    Vec,
    microfacet_geometry,
)
from render.tables import AngleTable, spectral_factor_table, table_index

__all__ = ["SpectralBackend", "TableBackend", "ALBEDO_TABLE_SIZE", "ALBEDO_GRAZING_COS"]

#: Nodes over cos_o of the directional-albedo tables of sky light (the albedo is
#: smooth in cos_o; the interpolation error is measured in the tests).  The
#: albedo vanishes at exactly cos_o = 0 by definition but tends to a finite
#: limit, so the first node is evaluated at ``ALBEDO_GRAZING_COS``.
ALBEDO_TABLE_SIZE = 65
ALBEDO_GRAZING_COS = 1e-4

# --------------------------------------------------------------------------- backends
def _lobe_key(lobe: Lobe) -> tuple:
    """The lobe group a lobe belongs to (as :func:`render.shading.plan_material` groups them)."""
    if lobe.kind == "lambert":
        return ("lambert", 0.0, "", 0.0)
    if lobe.kind == "anisotropic":
        return ("anisotropic", float(lobe.roughness), "smith", float(lobe.roughness_b))
    return ("microfacet", float(lobe.roughness), lobe.shadowing, 0.0)


def _group_key(group) -> tuple:
    return (group.kind, float(group.roughness), group.shadowing, float(group.roughness_b))


#: Directional albedo spectra already computed, per (lobe, nodes, grid): materials built from the
#: same preset share them, and a re-render does not integrate them again.  Only lobes whose spectral
#: factor has a value repr (ConductorFresnel, ...) are remembered; the default repr names an object.
_ALBEDO_CACHE: dict[tuple, NDArray[np.float64]] = {}


def _albedo_spectra(lobe: Lobe, cos_o: NDArray[np.float64], grid: SpectralGrid) -> NDArray[np.float64]:
    """Directional albedo ``(N, L)`` of one lobe including its weight, remembered (see ``_ALBEDO_CACHE``)."""
    text = repr(lobe.spectral)
    if " object at 0x" in text:
        return _albedo_spectra_uncached(lobe, cos_o, grid)
    key = (lobe.kind, lobe.weight, lobe.roughness, lobe.roughness_b, lobe.shadowing, text,
           cos_o.tobytes(), grid.start, grid.stop, grid.step)
    if key not in _ALBEDO_CACHE:
        if len(_ALBEDO_CACHE) > 256:
            _ALBEDO_CACHE.clear()
        _ALBEDO_CACHE[key] = _albedo_spectra_uncached(lobe, cos_o, grid)
    return _ALBEDO_CACHE[key]


def _albedo_spectra_uncached(lobe: Lobe, cos_o: NDArray[np.float64], grid: SpectralGrid) -> NDArray[np.float64]:
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


def _geometry_cos(group, ci: NDArray[np.float32], co: NDArray[np.float32], ch: NDArray[np.float32],
                  cd: NDArray[np.float32], tangential) -> NDArray[np.float32]:
    """Geometry factor times cos_i of one non-mirror lobe group, evaluated everywhere (no cut-off).

    Lambert: ``cos_i / pi``; anisotropic (cloth): the ellipsoid lobe, which needs ``tangential``
    (i_t, i_b, o_t, o_b); otherwise the microfacet geometry.  The table backend's direct and
    environment light share it.
    """
    if group.kind == "lambert":
        return ci * _F32(1.0 / math.pi)
    if group.kind == "anisotropic":
        if tangential is None:
            raise InputError("an anisotropic lobe needs the tangent frame of the hits")
        s = anisotropic_lobe(ci, co, ch, cd, *tangential, group.roughness, group.roughness_b)
    else:
        s = microfacet_geometry(ci, co, ch, cd, group.roughness, group.shadowing)
    s *= ci
    return s


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
        environment: EnvironmentPlan | None = None,
    ) -> None:
        self.grid = grid
        self.wavelengths = grid.wavelengths
        self.k = k
        self.lights = lights
        self.sky_radiance = sky_radiance
        self.plans = plans
        self.channels = grid.size
        self.environment = environment
        self.albedo: list[AngleTable | None] = []
        # directional albedo spectra (unscaled) of each non-mirror lobe group of each material: an
        # environment map lights each group through its own prefiltered map
        self.group_albedo_spectra: list[list[AngleTable]] = []
        self.env_materials: list[Material | None] = []
        nodes = np.linspace(0.0, 1.0, albedo_size)
        nodes[0] = ALBEDO_GRAZING_COS
        for plan in plans:
            self.env_materials.append(Material(plan.material.name, plan.sky_lobes) if plan.sky_lobes else None)
            if (sky.is_black and environment is None) or not plan.sky_lobes:
                self.albedo.append(None)
                self.group_albedo_spectra.append([])
                continue
            per_group = {_group_key(g): np.zeros((albedo_size, grid.size)) for g in plan.sky_groups}
            for lobe in plan.sky_lobes:
                per_group[_lobe_key(lobe)] += _albedo_spectra(lobe, nodes, grid)
            total = sum(per_group.values())
            self.group_albedo_spectra.append([AngleTable(v) for v in per_group.values()])
            self.albedo.append(None if sky.is_black else AngleTable(total * sky_radiance))

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

    # ---- environment map (image-based lighting); coefficients are (K, n) of the plan's basis
    def env_radiance(self, coeff: NDArray[np.float32]) -> NDArray[np.float64]:
        """Spectral radiance ``(n, L)`` of environment coefficients ``(K, n)``."""
        return np.asarray(coeff, np.float64).T @ self.environment.basis

    def env_direct(self, mat: int, ci: Vec, co: Vec, ch: Vec, cd: Vec, coeff: NDArray[np.float32], scale: Vec,
                   tangential: tuple[Vec, Vec, Vec, Vec] | None = None) -> NDArray[np.float64]:
        """Radiance of the non-mirror lobes lit from one environment direction per sample.

        Parameters
        ----------
        mat
            Global material number.
        ci, co, ch, cd
            Cosines of the samples, ``(n,)``.
        coeff
            ``(K, n)`` environment coefficients of the directions.
        scale
            ``(n,)`` estimator weight (visibility / density).
        tangential
            As for :meth:`direct`.

        Returns
        -------
        ndarray
            float64 ``(n, L)``.
        """
        if tangential is not None:
            tangential = tuple(np.asarray(x, np.float64) for x in tangential)
        f = material_brdf(self.env_materials[mat], ci, co, ch, cd, self.wavelengths, tangential)
        f *= (np.asarray(ci, np.float64) * scale)[:, None]
        f *= self.env_radiance(coeff)
        return f

    def env_diffuse(self, mat: int, cos_o: Vec, prefiltered: list[NDArray[np.float32]]) -> NDArray[np.float64]:
        """Unoccluded environment light of the non-mirror lobes: each group's albedo(cos_o) times its prefiltered map.

        Parameters
        ----------
        mat
            Global material number.
        cos_o
            ``(n,)`` cosines of the view direction.
        prefiltered
            ``(K, n)`` coefficients per lobe group of the material's non-mirror lobes: the
            cosine-weighted mean over each hemisphere (Lambert, cloth) or the map prefiltered by
            the lobe around the mirrored direction (microfacet lobes).

        Returns
        -------
        ndarray
            float64 ``(n, L)``.
        """
        out = np.zeros((len(cos_o), self.channels))
        for table, coeff in zip(self.group_albedo_spectra[mat], prefiltered):
            term = table.lookup(cos_o).astype(np.float64)
            term *= self.env_radiance(coeff)
            out += term
        return out

    def mirror_env(self, mat: int, j: int, cos_d: Vec, coeff: NDArray[np.float32], factor: Vec) -> NDArray[np.float64]:
        """The environment seen in mirror lobe ``j``: ``S(cos_d) * radiance(coeff) * factor``.

        Parameters
        ----------
        mat, j, cos_d
            As in :meth:`mirror_factor`.
        coeff
            ``(K, n)`` environment coefficients along the mirrored rays.
        factor
            ``(n,)`` ray weights.

        Returns
        -------
        ndarray
            float64 ``(n, L)``.
        """
        out = self.mirror_factor(mat, j, cos_d) * self.env_radiance(coeff)
        out *= np.asarray(factor, np.float64)[:, None]
        return out

    def env_background(self, coeff: NDArray[np.float32]) -> NDArray[np.float64]:
        """The environment's radiance ``(n, L)`` of coefficients ``(K, n)`` (camera rays that miss)."""
        return self.env_radiance(coeff)

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
        env = spectral.environment
        self.env_tables: list[list[AngleTable]] = []
        self.env_albedo_tables: list[list[AngleTable]] = []
        self.env_mirror_tables: list[list[AngleTable]] = []
        if env is not None:
            # every table holds the K basis spectra side by side: (N, 3 K) channels
            def stacked(factor, weight: float) -> AngleTable:
                parts = [spectral_factor_table(factor, b, grid, k * weight, size) for b in env.basis]
                n = max(p.size for p in parts)
                return AngleTable(np.concatenate([np.broadcast_to(p.values, (n, 3)) for p in parts], axis=1))

            for mat, plan in enumerate(plans):
                per_group = []
                for group in plan.sky_groups:
                    table = None
                    for weight, factor in group.members:
                        t = stacked(factor, weight)
                        table = t if table is None else table + t
                    per_group.append(table)
                self.env_tables.append(per_group)
                self.env_albedo_tables.append([AngleTable(np.concatenate(
                    [k * spectra_to_xyz(alb.values * b, grid) for b in env.basis], axis=1))
                    for alb in spectral.group_albedo_spectra[mat]])
                self.env_mirror_tables.append([stacked(lobe.spectral, 1.0) for lobe in plan.mirrors])
            self.env_xyz = (k * spectra_to_xyz(env.basis, grid)).astype(_F32)      # (K, 3)

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
                if index is None:
                    index = table_index(cd, self.size)
                s = _geometry_cos(group, ci, co, ch, cd, tangential)
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

    # ---- environment map (image-based lighting); coefficients are (K, n) of the plan's basis
    @staticmethod
    def _combine(stacked: NDArray[np.float32], weights: NDArray[np.float32]) -> NDArray[np.float32]:
        """``sum_k stacked[3k:3k+3] * weights[k]``: XYZ ``(3, n)`` of ``(3K, n)`` tables and ``(K, n)`` weights."""
        out = stacked[0:3] * weights[0]
        for c in range(1, weights.shape[0]):
            out += stacked[3 * c:3 * c + 3] * weights[c]
        return out

    def env_direct(self, mat: int, ci: Vec, co: Vec, ch: Vec, cd: Vec, coeff: NDArray[np.float32], scale: Vec,
                   tangential: tuple[Vec, Vec, Vec, Vec] | None = None) -> NDArray[np.float32]:
        """XYZ of the non-mirror lobes lit from one environment direction per sample.

        Parameters
        ----------
        mat, ci, co, ch, cd, coeff, scale, tangential
            As for :meth:`SpectralBackend.env_direct`.

        Returns
        -------
        ndarray
            float32 XYZ ``(3, n)``.
        """
        plan = self.plans[mat]
        out = self.zeros(len(ci))
        index = table_index(cd, self.size)
        for group, table in zip(plan.sky_groups, self.env_tables[mat]):
            g = (_geometry_cos(group, ci, co, ch, cd, tangential) * scale).astype(_F32, copy=False)
            stacked = table.lookup_channels(cd) if table.constant else table.lookup_channels(index=index)
            out += self._combine(stacked, coeff * g)
        return out

    def env_diffuse(self, mat: int, cos_o: Vec, prefiltered: list[NDArray[np.float32]]) -> NDArray[np.float32]:
        """Unoccluded environment light of the non-mirror lobes from the albedo tables (see the spectral backend).

        Parameters
        ----------
        mat, cos_o, prefiltered
            As for :meth:`SpectralBackend.env_diffuse`.

        Returns
        -------
        ndarray
            float32 XYZ ``(3, n)``.
        """
        tables = self.env_albedo_tables[mat]
        index = table_index(cos_o, tables[0].size)
        out = self.zeros(len(cos_o))
        for table, coeff in zip(tables, prefiltered):
            out += self._combine(table.lookup_channels(index=index), coeff)
        return out

    def mirror_env(self, mat: int, j: int, cos_d: Vec, coeff: NDArray[np.float32], factor: Vec) -> NDArray[np.float32]:
        """XYZ of the environment seen in mirror lobe ``j`` (see the spectral backend).

        Parameters
        ----------
        mat, j, cos_d, coeff, factor
            As for :meth:`SpectralBackend.mirror_env`.

        Returns
        -------
        ndarray
            float32 XYZ ``(3, n)``.
        """
        return self._combine(self.env_mirror_tables[mat][j].lookup_channels(cos_d), coeff * np.asarray(factor, _F32))

    def env_background(self, coeff: NDArray[np.float32]) -> NDArray[np.float32]:
        """XYZ ``(3, n)`` of environment coefficients ``(K, n)``."""
        return np.ascontiguousarray(self.env_xyz.T @ np.asarray(coeff, _F32))

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
