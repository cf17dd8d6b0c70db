"""The shading integrator: direct light with shadow rays, sky and environment light, one mirror bounce.

:func:`shade` sums, for each ray hit, the colour signal of Matsuda et al.,
eq. (2) and (5), over the lights and lobes of its material (the formula and
its approximations are in :mod:`render.shading` and docs/rendering.md); the
spectral part comes from one of the backends of :mod:`render.backends`.

An environment map (:mod:`render.environment`) lights the non-mirror lobes
of the primary hits by Monte Carlo integration when ``environment_samples``
is above 0: half the directions drawn from the map's luminance above its
mean, half from the lobes' BRDF (cosine for Lambert and cloth lobes,
Beckmann normals for microfacet lobes), combined by the balance heuristic
of multiple importance sampling (Veach and Guibas 1995,
doi:10.1145/218380.218498), each with a shadow ray when ``shadows`` is set.
With no samples (and on the mirror bounce's secondary hits) each lobe group
takes its directional albedo times the map prefiltered by the group (the
cosine lobe at the normal, or a glossy lobe around the mirrored view: the
split-sum approximation), unoccluded.  Mirror lobes see the map along their
mirrored rays where those miss the scene.
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
from render.environment import EnvironmentPlan
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
    orthonormal_basis,
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
    environment
        The environment map prepared for shading, or None.
    environment_samples
        Directions per primary hit for the environment light of the
        non-mirror lobes (0: the prefiltered map, unoccluded).
    environment_term
        The sampled environment light of the last primary :func:`shade`
        call (its colours, included in what it returned), or None: the
        renderer leaves its Monte Carlo noise out of the adaptive
        anti-aliasing decision.
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
    environment: EnvironmentPlan | None = None
    environment_samples: int = 0
    environment_term: NDArray | None = None

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
    sampled_env = ctx.environment is not None and ctx.environment_samples > 0 and depth == ctx.mirror_bounces
    env_out = backend.zeros(m) if sampled_env else None
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
        # ---- environment map through the non-mirror lobes
        if ctx.environment is not None and plan.sky_groups:
            sub = hits if sel is None else hits.take(sel)
            if sampled_env:
                _environment_light(ctx, sub, sel, env_out, backend, mat, rng)
            else:
                backend.add(out, sel, backend.env_diffuse(mat, sub.cos_o, _prefiltered(ctx, sub, plan)))
        # ---- mirror lobes
        for j, lobe in enumerate(plan.mirrors):
            _mirror(ctx, hits if sel is None else hits.take(sel), sel, out, backend, mat, j, lobe, depth, rng)
    if sampled_env:
        out += env_out
        ctx.environment_term = env_out
    return out


def _mirror(ctx: ShadingContext, sub: Hits, sel: NDArray[np.intp] | None, out: NDArray,
            backend: SpectralBackend | TableBackend, mat: int, j: int, lobe: Lobe, depth: int,
            rng: np.random.Generator) -> None:
    """Add mirror lobe ``j`` of material ``mat`` for the hits ``sub`` (rows ``sel`` of ``out``)."""
    co = sub.cos_o
    weight = _F32(lobe.weight)
    if depth <= 0:
        r = _reflect(sub.view, sub.shading_normal, co)
        _mirror_surroundings(ctx, backend, out, sel, mat, j, r, co, np.full(len(sub), weight, dtype=_F32))
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
        miss = np.flatnonzero(~hit)
        if miss.size:
            idx = None if (sel is None and miss.size == len(sub)) else target[miss]
            _mirror_surroundings(ctx, backend, out, idx, mat, j, np.take(r_rows, miss, axis=1),
                                 np.take(cd_rows, miss), np.take(w_rows, miss))
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


def _prefiltered(ctx: ShadingContext, sub: Hits, plan: MaterialPlan) -> list[NDArray[np.float32]]:
    """Prefiltered environment coefficients ``(K, m)`` per non-mirror lobe group of ``plan``.

    The cosine-prefiltered map at the normal for Lambert and cloth groups, the map prefiltered by
    the lobe around the mirrored view for microfacet groups.
    """
    env = ctx.environment
    out = []
    irr = r = None
    for group in plan.sky_groups:
        if group.kind == "microfacet":
            if r is None:
                r = _reflect(sub.view, sub.shading_normal, sub.cos_o)
            out.append(env.glossy(r, group.roughness))
        else:
            if irr is None:
                irr = env.irradiance(sub.shading_normal)
            out.append(irr)
    return out


def _mirror_surroundings(ctx: ShadingContext, backend: SpectralBackend | TableBackend, out: NDArray,
                         idx: NDArray[np.intp] | None, mat: int, j: int, r: NDArray[np.float32],
                         cd: NDArray[np.float32], w: NDArray[np.float32]) -> None:
    """Add the sky and the environment map seen along mirrored rays ``r`` (3, n) with weights ``w`` to rows ``idx``."""
    if not ctx.sky.is_black:
        factor = ctx.sky.radiance_scale(r.T).astype(_F32) * w
        backend.add(out, idx, backend.mirror_sky(mat, j, cd, factor))
    if ctx.environment is not None:
        backend.add(out, idx, backend.mirror_env(mat, j, cd, ctx.environment.lookup(r), w))


# --------------------------------------------------------------------------- environment light
def _group_weights(plan_groups) -> NDArray[np.float64]:
    """Probabilities of choosing each lobe group for BRDF sampling: its share of the lobe weights."""
    w = np.array([sum(weight for weight, _ in g.members) for g in plan_groups], dtype=np.float64)
    return w / w.sum()


def _sample_brdf(groups, probabilities: NDArray[np.float64], normal: NDArray[np.float32], view: NDArray[np.float32],
                 frame: tuple[NDArray[np.float32], NDArray[np.float32]], rng: np.random.Generator,
                 stratum: tuple[int, int] = (0, 1)) -> NDArray[np.float32]:
    """One direction ``(3, m)`` per hit from the mixture of the lobe groups' sampling densities.

    ``frame`` is :func:`orthonormal_basis` of ``normal``; ``stratum`` ``(s, n)`` restricts the cosine
    directions to the s-th of n rings of equal probability.
    """
    m = normal.shape[1]
    u = rng.random((3, m), dtype=_F32)
    u[1] = (_F32(stratum[0]) + u[1]) * _F32(1.0 / stratum[1])
    # cosine-weighted hemisphere (Lambert and anisotropic groups; Malley's method)
    t, b = frame
    r = np.sqrt(u[1])
    phi = _F32(2.0 * math.pi) * u[2]
    d = t * (r * np.cos(phi))
    d += b * (r * np.sin(phi))
    d += normal * np.sqrt(np.maximum(_F32(1.0) - u[1], _F32(0.0)))
    choice = np.searchsorted(np.cumsum(probabilities)[:-1], u[0], side="right")
    for g, group in enumerate(groups):
        if group.kind != "microfacet":
            continue
        rows = np.flatnonzero(choice == g)
        if rows.size == 0:
            continue
        n_rows = _take(normal, rows)
        v_rows = _take(view, rows)
        h = sample_beckmann_normals(n_rows, group.roughness, rng)
        d[:, rows] = _reflect(v_rows, h, dot3(v_rows, h))
    return d


def _brdf_pdf(groups, probabilities: NDArray[np.float64], normal: NDArray[np.float32], view: NDArray[np.float32],
              d: NDArray[np.float32], ci: NDArray[np.float32]) -> NDArray[np.float32]:
    """Density ``(m,)`` in 1/sr of :func:`_sample_brdf` for directions ``d``."""
    pdf = np.zeros(d.shape[1], dtype=_F32)
    cos_pdf = np.maximum(ci, _F32(0.0)) * _F32(1.0 / math.pi)
    h = None
    for p, group in zip(probabilities, groups):
        if group.kind != "microfacet":
            pdf += _F32(p) * cos_pdf
            continue
        if h is None:
            h = view + d
            _normalise(h)
            ch = np.clip(dot3(normal, h), _F32(1e-6), _F32(1.0))
            vh = np.maximum(np.abs(dot3(view, h)), _F32(1e-6))
        s2 = _F32(group.roughness * group.roughness)
        c2 = ch * ch
        with np.errstate(over="ignore", under="ignore"):
            dist = np.exp((_F32(1.0) - _F32(1.0) / c2) / s2) / (_F32(math.pi) * s2 * c2 * c2)
        pdf += _F32(p) * dist * ch / (_F32(4.0) * vh)
    return pdf


def _environment_light(ctx: ShadingContext, sub: Hits, sel: NDArray[np.intp] | None, out: NDArray,
                       backend: SpectralBackend | TableBackend, mat: int, rng: np.random.Generator) -> None:
    """Add the environment light of material ``mat``'s non-mirror lobes for the hits ``sub`` (MIS, shadow rays)."""
    env = ctx.environment
    plan = ctx.plans[mat]
    groups = plan.sky_groups
    probabilities = _group_weights(groups)
    total = ctx.environment_samples
    n_light = total // 2 if env.samples_map else 0
    n_brdf = total - n_light
    m = len(sub)
    ns, v, co = sub.shading_normal, sub.view, sub.cos_o
    tb = None
    if plan.anisotropic:
        if sub.tangent is None:
            raise InputError(f"material {plan.material.name!r} is anisotropic but the hits carry no tangents")
        tb = (sub.tangent, cross3(ns, sub.tangent))
    frame = orthonormal_basis(ns)
    for s in range(total):
        if s < n_light:
            d, pdf_l, pixel = env.sample(m, rng, (s, n_light))
        else:
            d = _sample_brdf(groups, probabilities, ns, v, frame, rng, (s - n_light, n_brdf))
            pixel = env.pixel_index(d)
            pdf_l = env.pdf_of(pixel) if n_light else np.zeros(m, _F32)
        ci = dot3(ns, d)
        pdf_b = _brdf_pdf(groups, probabilities, ns, v, d, ci) if n_brdf else np.zeros(m, _F32)
        denom = _F32(n_light) * pdf_l + _F32(n_brdf) * pdf_b
        ok = (ci > 0) & (denom > 0)
        rows = np.flatnonzero(ok)
        if rows.size and ctx.shadows:
            d_rows = _take(d, rows)
            origins = _offset_origins(_take(sub.position, rows), _take(sub.geometric_normal, rows), d_rows,
                                      ctx.offset)
            blocked = ctx.occluded(_rays(origins, d_rows), math.inf)
            ctx.count("environment_rays", rows.size)
            rows = rows[~blocked]
        if rows.size == 0:
            continue
        all_rows = rows.size == m
        key = None if all_rows else rows
        d_r = _take(d, key)
        v_r = _take(v, key)
        h = v_r + d_r
        _normalise(h)
        ns_r = _take(ns, key)
        ci_r = _take(ci, key)
        coeff_r = env.radiance_of(pixel if all_rows else np.take(pixel, rows))
        scale = _F32(1.0) / _take(denom, key)
        tangential = None
        if tb is not None:
            t_r, b_r = _take(tb[0], key), _take(tb[1], key)
            tangential = (dot3(t_r, d_r), dot3(b_r, d_r), dot3(t_r, v_r), dot3(b_r, v_r))
        term = backend.env_direct(mat, ci_r, _take(co, key), dot3(ns_r, h),
                                  np.clip(dot3(v_r, h), _F32(0.0), _F32(1.0)), coeff_r, scale, tangential)
        target = rows if sel is None else sel[rows]
        backend.add(out, None if (all_rows and sel is None) else target, term)
