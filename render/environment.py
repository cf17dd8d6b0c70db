"""Image-based lighting: an environment map prepared for shading.

:class:`EnvironmentPlan` holds what the integrator (:mod:`render.integrator`)
needs of a :class:`~processing.lighting.environment_map.EnvironmentMap`:

* the **basis spectra on the render's grid**, divided by the renderer's XYZ
  normalisation ``k``, so that a direction's spectral radiance in render
  units is ``coefficients(d) @ basis`` (spectra stay ``K`` coefficients
  until they meet a lobe's table or BRDF).  The map's luminance is the
  render's luminance: a white Lambertian surface under a uniform map of
  luminance ``Y`` renders with ``Y``, whatever the key light;
* **importance sampling** of the map: a pixel is drawn with probability
  proportional to its luminance above the map's mean luminance times its
  solid angle (one CDF over all pixels), then a direction uniformly in
  solid angle within the pixel; the density of a direction is
  ``P(pixel) / Omega(pixel)`` (Pharr, Jakob and Humphreys 2016, section
  14.2.4).  Subtracting the mean is the MIS compensation of Karlik et al.
  (2019): the BRDF samples the integrator combines with these take the
  uniform part of the light, so a uniform map is sampled by the BRDF alone
  (no noise in the furnace) and a sun by the map.  Radiance for these
  samples is the pixel's own (piecewise constant, the same function the
  density follows);
* the **cosine-prefiltered map**: ``(1/pi) int L(w) max(0, n . w) dw`` for
  normals ``n`` on a coarse grid, bilinear in between: the radiance a
  white Lambertian surface facing ``n`` reflects when nothing occludes it
  (used by the ``draft`` preset and for the mirror bounce's secondary hits),
  and, for glossy lobes, the map prefiltered by the lobe around the mirrored
  direction (the split-sum approximation);
* bilinear **lookups** for mirror reflections and the background.

References
----------
Debevec, P. (1998). Rendering synthetic objects into real scenes.
SIGGRAPH 98, 189-198. doi:10.1145/280814.280864
Veach, E., & Guibas, L. J. (1995). Optimally combining sampling techniques
for Monte Carlo rendering. SIGGRAPH 95, 419-428. doi:10.1145/218380.218498
Karlik, O., Sik, M., Vevoda, P., Skrivanek, T., & Krivanek, J. (2019). MIS
compensation: optimizing sampling techniques in multiple importance
sampling. ACM TOG 38(6), 151. doi:10.1145/3355089.3356565
Karis, B. (2013). Real shading in Unreal Engine 4. SIGGRAPH 2013 course
Physically Based Shading in Theory and Practice (split-sum approximation; no DOI).
Pharr, M., Jakob, W., & Humphreys, G. (2016). Physically Based Rendering,
3rd ed., section 14.2.4 (infinite area lights). doi:10.1016/C2013-0-15557-2

Examples
--------
>>> from processing.lighting.environment_map import uniform_environment
>>> from processing.spectral.spectra import SpectralGrid
>>> plan = EnvironmentPlan.build(uniform_environment(0.5, height=8), SpectralGrid(400, 700, 10), k=1.0)
>>> n = np.array([[0.0], [0.0], [1.0]], dtype=np.float32)
>>> plan.irradiance(n).ravel().round(3).tolist()      # a uniform map: its own radiance
[0.5, 0.5, 0.5]
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from processing.lighting.environment_map import EnvironmentMap, EnvironmentMapError
from processing.spectral.display import spectra_to_xyz
from processing.spectral.spectra import SpectralGrid, resample

__all__ = ["EnvironmentPlan", "IRRADIANCE_HEIGHT", "IRRADIANCE_SOURCE_HEIGHT", "NEGATIVE_SHARE", "check_environment_light"]

_F32 = np.float32

#: Rows of the cosine-prefiltered map (its width is twice that); the cosine
#: lobe is smooth: a Lambertian sphere under a sky with a sun agrees with the
#: sampled integral to 0.04 % in the mean and 1.4 % (95th percentile) in 4 x 4
#: pixel blocks (tests/render/test_render_environment.py).
IRRADIANCE_HEIGHT = 16

#: Rows of the area-averaged copy of the map the prefiltering integrates (power kept).
IRRADIANCE_SOURCE_HEIGHT = 32


def _row_solid_angles(height: int, width: int) -> NDArray[np.float64]:
    edges = np.pi * np.arange(height + 1) / height
    return (np.cos(edges[:-1]) - np.cos(edges[1:])) * (2.0 * np.pi / width)


def _area_average(coefficients: NDArray[np.float32], height: int) -> NDArray[np.float64]:
    """The map reduced to ``height x 2 height`` pixels by solid-angle-weighted averaging (power kept)."""
    h, w, k = coefficients.shape
    if h <= height:
        return coefficients.astype(np.float64)
    width = 2 * height
    omega = _row_solid_angles(h, w)
    ti = (np.arange(h) * height) // h
    tj = (np.arange(w) * width) // w
    target = (ti[:, None] * width + tj[None, :]).ravel()
    wgt = np.repeat(omega, w)
    out = np.empty((height * width, k))
    total = np.bincount(target, weights=wgt, minlength=height * width)
    for c in range(k):
        out[:, c] = np.bincount(target, weights=coefficients[..., c].ravel() * wgt, minlength=height * width)
    out /= total[:, None]
    return out.reshape(height, width, k)


#: Most negative pixel luminance (and mean or white spectrum value) :func:`check_environment_light` lets
#: pass, as a share of the brightest: a map measured from photos dips below zero in its dark pixels by
#: their noise, far less than this; a map with a negative spectral basis goes as far below as above.
NEGATIVE_SHARE = 1e-2


def check_environment_light(env: EnvironmentMap) -> None:
    """Refuse a map that gives no light, negative light or light float32 shading cannot hold.

    The luminance of the map's brightest pixel, intensity applied (render
    units: 1 is display white), must lie in
    ``render.limits.ENVIRONMENT_LUMINANCE_RANGE``; the luminance of every
    pixel, the map's mean radiance spectrum and its white must not be
    negative (a negative spectral basis in a kogei header) beyond
    :data:`NEGATIVE_SHARE` of the brightest (a measured map's noise).

    Parameters
    ----------
    env
        The map, its intensity included.

    Raises
    ------
    EnvironmentMapError
        One line naming ``env.source``, the value and the remedy.
    """
    from render.limits import ENVIRONMENT_LUMINANCE_RANGE

    low, high = ENVIRONMENT_LUMINANCE_RANGE
    y_of_basis = spectra_to_xyz(env.basis, env.grid)[:, 1]
    unit = float(np.abs(y_of_basis).max()) or 1.0                     # keeps the float32 product finite
    c = env.coefficients.reshape(-1, env.coefficients.shape[2])
    with np.errstate(over="ignore", invalid="ignore"):
        y = c @ (y_of_basis / unit).astype(_F32)
        peak = float(np.max(y)) * unit * env.intensity
        lowest = float(np.min(y)) * unit * env.intensity
        spectra = np.stack([env.mean_radiance_spectrum(), env.white_spectrum()])
    scale = max(abs(peak), abs(lowest))
    # a measured map's dark pixels may dip below zero by their noise; a negative basis shows far beyond it
    negative = lowest < -NEGATIVE_SHARE * scale or float(spectra.min()) < -NEGATIVE_SHARE * float(np.abs(spectra).max())
    if negative or peak < 0:
        raise EnvironmentMapError(f"{env.source}: the map's radiance is negative (lowest pixel luminance "
                                  f"{lowest:.3g}; its spectral basis is negative): radiance cannot be negative, "
                                  "write the map again with kogei")
    if not peak >= low:
        raise EnvironmentMapError(f"{env.source}: the map gives no light (brightest pixel luminance {peak:.3g} with "
                                  f"intensity {env.intensity:g}; at least {low:g} is needed, 1 = display white): "
                                  "give a map that records light or raise its intensity")
    if not (math.isfinite(peak) and peak <= high):
        raise EnvironmentMapError(f"{env.source}: the brightest pixel has luminance {peak:.3g} with intensity "
                                  f"{env.intensity:g}, above {high:g} (1 = display white; float32 shading "
                                  "overflows): lower its intensity or export the map in a smaller unit")


#: Plans already built, per map and (grid, k): a re-render of the same scene (the window's preview)
#: does not integrate the map again.
_PLANS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_PREFILTERED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_GLOSSY: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


@dataclass(frozen=True, eq=False)
class EnvironmentPlan:
    """An environment map prepared for shading (see the module notes).

    Attributes
    ----------
    environment
        The map (rotation and intensity are its own).
    basis
        ``(K, L)`` radiance of a unit coefficient on the render grid, divided by ``k``.
    cdf
        ``(H W,)`` cumulative pixel probabilities (luminance above the mean x solid angle), last = 1.
    pixel_pdf
        ``(H, W)`` density in 1/sr of a direction inside each pixel.
    samples_map
        False when no pixel is above the mean (a uniform map): only the BRDF is sampled.
    coefficients_t, pixel_pdf_flat, row_cos
        float32 copies for sampling: ``(K, H W)`` coefficients (intensity applied), ``(H W,)``
        densities, ``(H + 1,)`` cosines of the row edges.
    irradiance_map
        The cosine-prefiltered coefficients as an :class:`EnvironmentMap` (intensity 1, the same rotation).
    white_basis
        ``(L,)`` the spectrum of a unit coefficient in every basis row (the white of a scene without lights).
    """

    environment: EnvironmentMap
    basis: NDArray[np.float64]
    cdf: NDArray[np.float64]
    pixel_pdf: NDArray[np.float64]
    irradiance_map: EnvironmentMap
    white_basis: NDArray[np.float64]
    samples_map: bool = True
    coefficients_t: NDArray[np.float32] | None = None
    pixel_pdf_flat: NDArray[np.float32] | None = None
    row_cos: NDArray[np.float32] | None = None

    @classmethod
    def build(cls, env: EnvironmentMap, grid: SpectralGrid, k: float) -> EnvironmentPlan:
        """Prepare ``env`` for a render on ``grid`` whose XYZ normalisation is ``k``.

        Parameters
        ----------
        env
            The environment map.
        grid
            The render's wavelength grid.
        k
            The render's XYZ scale (rendered radiance times ``k`` is shown XYZ).

        Returns
        -------
        EnvironmentPlan
            The plan.
        """
        b = cls.basis_on_grid(env, grid)
        omega = _row_solid_angles(env.height, env.width)[:, None]
        y = env.pixel_luminance()
        mean = float((y * omega).sum() / (4.0 * math.pi))
        lum = np.maximum(y - mean, 0.0) * omega
        total = float(lum.sum())
        samples_map = total > 1e-6 * mean * 4.0 * math.pi
        if samples_map:
            cdf = np.cumsum(lum.ravel()) / total
            pdf = lum / total / _row_solid_angles(env.height, env.width)[:, None]
        else:
            cdf = np.arange(1, lum.size + 1) / lum.size
            pdf = np.full(lum.shape, 1.0 / (4.0 * math.pi))
        cdf[-1] = 1.0
        irr = _PREFILTERED.get(env)
        if irr is None:
            irr = _PREFILTERED[env] = _cosine_prefilter(env)
        irr_map = EnvironmentMap(irr.astype(np.float32), env.basis, env.grid, source=env.source,
                                 rotation_deg=env.rotation_deg, intensity=1.0)
        coeff_t = np.ascontiguousarray((env.coefficients.reshape(-1, env.coefficients.shape[2])
                                        * _F32(env.intensity)).T, dtype=_F32)
        row_cos = np.cos(np.pi * np.arange(env.height + 1) / env.height).astype(_F32)
        return cls(env, b / k, cdf, pdf, irr_map, b.sum(axis=0), samples_map, coeff_t,
                   pdf.ravel().astype(_F32), row_cos)

    @classmethod
    def cached(cls, env: EnvironmentMap, grid: SpectralGrid, k: float) -> EnvironmentPlan:
        """:meth:`build`, remembered for as long as ``env`` lives (same arguments: the same plan)."""
        per_map = _PLANS.setdefault(env, {})
        key = (grid.start, grid.stop, grid.step, float(k))
        if key not in per_map:
            per_map[key] = cls.build(env, grid, k)
        return per_map[key]

    @staticmethod
    def basis_on_grid(env: EnvironmentMap, grid: SpectralGrid) -> NDArray[np.float64]:
        """``(K, L)``: the map's basis resampled to ``grid``, each row keeping its luminance."""
        return EnvironmentPlan.spectrum_on_grid(env.basis, env.grid, grid)

    @staticmethod
    def spectrum_on_grid(spectra: NDArray[np.float64], source: SpectralGrid, grid: SpectralGrid) -> NDArray[np.float64]:
        """Spectra ``(..., n)`` on ``source`` resampled to ``grid``, each keeping its luminance."""
        s = np.atleast_2d(np.asarray(spectra, dtype=np.float64))
        b = resample(source.wavelengths, s, grid)
        y_src = spectra_to_xyz(s, source)[:, 1]
        y_dst = spectra_to_xyz(b, grid)[:, 1]
        out = b * np.where(y_dst > 0, y_src / np.where(y_dst > 0, y_dst, 1.0), 1.0)[:, None]
        return out if np.ndim(spectra) == 2 else out[0]

    @property
    def channels(self) -> int:
        """Number of basis spectra K."""
        return int(self.basis.shape[0])

    def lookup(self, directions: NDArray[np.float32]) -> NDArray[np.float32]:
        """Coefficients ``(K, m)`` along ``(3, m)`` unit directions, bilinear (mirror rays, background).

        The float32 counterpart of :meth:`EnvironmentMap.lookup` (clamped at the poles, wrapping in azimuth).
        """
        env = self.environment
        d = np.asarray(directions, dtype=_F32)
        h, w = env.height, env.width
        r = np.arccos(np.clip(d[2], _F32(-1.0), _F32(1.0))) * _F32(h / math.pi) - _F32(0.5)
        r = np.clip(r, _F32(0.0), _F32(h - 1))
        c = (np.arctan2(d[1], d[0]) - _F32(math.radians(env.rotation_deg))) * _F32(w / (2.0 * math.pi)) - _F32(0.5)
        r0 = np.minimum(r.astype(np.intp), h - 2) if h > 1 else np.zeros(r.shape, np.intp)
        fr = r - r0.astype(_F32)
        c0f = np.floor(c)
        fc = c - c0f
        c0 = np.mod(c0f.astype(np.intp), w)
        c1 = np.mod(c0 + 1, w)
        top, bottom = r0 * w, (r0 + 1) * w
        m = self.coefficients_t
        out = np.take(m, top + c0, axis=1) * ((_F32(1.0) - fc) * (_F32(1.0) - fr))
        out += np.take(m, top + c1, axis=1) * (fc * (_F32(1.0) - fr))
        out += np.take(m, bottom + c0, axis=1) * ((_F32(1.0) - fc) * fr)
        out += np.take(m, bottom + c1, axis=1) * (fc * fr)
        return out

    def irradiance(self, normals: NDArray[np.float32]) -> NDArray[np.float32]:
        """Cosine-weighted mean coefficients ``(K, m)`` over the hemispheres of ``(3, m)`` unit normals."""
        return np.ascontiguousarray(self.irradiance_map.lookup(np.asarray(normals, np.float64).T).T, dtype=_F32)

    def glossy(self, directions: NDArray[np.float32], roughness: float) -> NDArray[np.float32]:
        """Coefficients ``(K, m)`` of the map prefiltered by a Beckmann lobe of ``roughness`` around ``(3, m)`` directions.

        The kernel is the lobe's spread of mirrored directions at normal incidence: a
        direction at angle ``theta`` from the mirrored one has its half vector
        ``theta / 2`` from the normal, weight ``exp(-tan^2(theta / 2) / sigma^2)``
        (normalised over the sphere).  With the lobe's directional albedo this is the
        split-sum approximation (Karis 2013) the ``draft`` preset uses for glossy lobes.
        """
        env = self.environment
        per_map = _GLOSSY.setdefault(env, {})
        sigma = float(roughness)
        if sigma not in per_map:
            per_map[sigma] = EnvironmentMap(_lobe_prefilter(env, sigma).astype(np.float32), env.basis, env.grid,
                                            source=env.source, rotation_deg=env.rotation_deg, intensity=1.0)
        return np.ascontiguousarray(per_map[sigma].lookup(np.asarray(directions, np.float64).T).T, dtype=_F32)

    def pixel_index(self, directions: NDArray[np.float32]) -> NDArray[np.intp]:
        """Flat index ``row * W + column`` ``(m,)`` of the pixels holding ``(3, m)`` unit directions."""
        env = self.environment
        d = np.asarray(directions, dtype=_F32)
        h, w = env.height, env.width
        theta = np.arccos(np.clip(d[2], _F32(-1.0), _F32(1.0)))
        i = np.minimum((theta * _F32(h / math.pi)).astype(np.intp), h - 1)
        phi = np.arctan2(d[1], d[0]) - _F32(math.radians(env.rotation_deg))
        j = np.mod(np.floor(phi * _F32(w / (2.0 * math.pi))).astype(np.intp), w)
        return i * w + j

    def pdf_of(self, index: NDArray[np.intp]) -> NDArray[np.float32]:
        """Density ``(m,)`` in 1/sr of :meth:`sample` inside the pixels ``index`` (flat)."""
        return np.take(self.pixel_pdf_flat, index)

    def radiance_of(self, index: NDArray[np.intp]) -> NDArray[np.float32]:
        """Coefficients ``(K, m)`` of the pixels ``index`` (flat; intensity applied)."""
        return np.take(self.coefficients_t, index, axis=1)

    def pdf(self, directions: NDArray[np.float32]) -> NDArray[np.float32]:
        """Density ``(m,)`` in 1/sr with which :meth:`sample` draws ``(3, m)`` unit directions."""
        return self.pdf_of(self.pixel_index(directions))

    def radiance_nearest(self, directions: NDArray[np.float32]) -> NDArray[np.float32]:
        """Coefficients ``(K, m)`` of the pixels holding ``(3, m)`` directions (piecewise constant)."""
        return self.radiance_of(self.pixel_index(directions))

    def sample(self, m: int, rng: np.random.Generator, stratum: tuple[int, int] = (0, 1)
               ) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.intp]]:
        """Draw ``m`` directions by luminance: ``(3, m)`` directions, ``(m,)`` densities, ``(m,)`` pixels.

        Parameters
        ----------
        m
            Number of directions.
        rng
            Random generator.
        stratum
            ``(s, n)``: draw from the s-th of n equal slices of the luminance CDF
            (stratified sampling over n calls; the density is that of the whole map).

        Returns
        -------
        tuple of ndarray
            Directions, their densities in 1/sr and the flat indices of their pixels
            (:meth:`radiance_of` gives their coefficients).
        """
        env = self.environment
        u0 = (stratum[0] + rng.random(m)) / stratum[1]
        flat = np.minimum(np.searchsorted(self.cdf, u0, side="right"), self.cdf.size - 1)
        i, j = np.divmod(flat, env.width)
        u = rng.random((2, m), dtype=_F32)
        z0 = np.take(self.row_cos, i)
        z = z0 + (np.take(self.row_cos, i + 1) - z0) * u[0]
        phi = (j.astype(_F32) + u[1]) * _F32(2.0 * math.pi / env.width) + _F32(math.radians(env.rotation_deg))
        s = np.sqrt(np.maximum(_F32(1.0) - z * z, _F32(0.0)))
        d = np.stack([s * np.cos(phi), s * np.sin(phi), z])
        return d, self.pdf_of(flat), flat


def _cosine_prefilter(env: EnvironmentMap) -> NDArray[np.float64]:
    """``(h, 2h, K)``: ``(1/pi) int L(w) max(0, n . w) dw`` for the pixel-centre normals of a coarse map.

    The source is the map area-averaged to ``IRRADIANCE_SOURCE_HEIGHT`` rows (power kept); intensity applied.
    """
    src = _area_average(env.coefficients, IRRADIANCE_SOURCE_HEIGHT) * env.intensity
    hs, ws, k = src.shape
    from processing.lighting.environment_map import pixel_directions

    d_src = pixel_directions(hs, ws).reshape(-1, 3)
    w_src = np.repeat(_row_solid_angles(hs, ws), ws)
    h = min(IRRADIANCE_HEIGHT, env.height)
    d_out = pixel_directions(h, 2 * h).reshape(-1, 3)
    kernel = np.maximum(d_out.astype(_F32) @ d_src.T.astype(_F32), _F32(0.0))
    kernel *= (w_src / math.pi).astype(_F32)[None, :]
    out = (kernel @ src.reshape(-1, k).astype(_F32)).astype(np.float64)
    return out.reshape(h, 2 * h, k)


def _lobe_prefilter(env: EnvironmentMap, sigma: float) -> NDArray[np.float64]:
    """``(h, 2h, K)``: the map averaged with the weight ``exp(-tan^2(theta / 2) / sigma^2)`` around each pixel centre.

    ``h`` follows the lobe's width (16 rows for sigma >= 0.19, up to 64 for sharper lobes); the source is the
    map area-averaged to the same height (intensity applied).
    """
    h = int(min(64, max(16, math.ceil(3.0 / max(sigma, 1e-3)))))
    h = min(h, env.height)
    src = _area_average(env.coefficients, h) * env.intensity
    hs, ws, k = src.shape
    from processing.lighting.environment_map import pixel_directions

    d_src = pixel_directions(hs, ws).reshape(-1, 3).astype(_F32)
    w_src = np.repeat(_row_solid_angles(hs, ws), ws).astype(_F32)
    d_out = pixel_directions(h, 2 * h).reshape(-1, 3).astype(_F32)
    flat = src.reshape(-1, k).astype(_F32)
    out = np.empty((d_out.shape[0], k))
    for start in range(0, d_out.shape[0], 512):                      # bounded memory: 512 x hs ws at a time
        c = np.clip(d_out[start:start + 512] @ d_src.T, _F32(-1.0), _F32(1.0))
        # tan^2(theta / 2) = (1 - cos theta) / (1 + cos theta)
        with np.errstate(divide="ignore", over="ignore", under="ignore"):
            t2 = (_F32(1.0) - c) / np.maximum(_F32(1.0) + c, _F32(1e-12))
            kernel = np.exp(-t2 / _F32(sigma * sigma)) * w_src[None, :]
        total = kernel.sum(axis=1, keepdims=True)
        out[start:start + 512] = (kernel @ flat) / np.maximum(total, _F32(1e-30))
    return out.reshape(h, 2 * h, k)
