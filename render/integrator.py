"""The shading integrator: direct light with shadow rays, sky light, one mirror bounce.

:func:`shade` sums, for each ray hit, the colour signal of Matsuda et al.,
eq. (2) and (5), over the lights and lobes of its material (the formula and
its approximations are in :mod:`render.shading` and docs/rendering.md); the
spectral part comes from one of the backends of :mod:`render.backends`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from processing.errors import InputError
from processing.materials.lobes import Lobe
from render.backends import SpectralBackend, TableBackend
from render.scene import Sky
from render.shading import (
    _F32,
    Hits,
    LightPlan,
    MaterialPlan,
    _mirror_g,
    _normalise,
    _take,
    cross3,
    dot3,
    sample_beckmann_normals,
)

__all__ = ["ShadingContext", "light_samples", "shade"]

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
