"""Fit the cloth model to RAW frames of a swatch on the turntable (robust least squares).

The measurement of ``kogei cloth fit``: a flat swatch on the table, camera
and light fixed (:mod:`processing.cloth.swatch_geometry`), one RAW frame per
table angle and a colour chart frame; turning the table turns the yarn under
a fixed light and view, which is what the anisotropic lobes respond to.  A
chart gives per-channel gains to camera responses; the model predicts the
same responses per photosite; the ellipsoid axes, the three weights and the
dye (as an sRGB colour) are fitted with a soft-L1 loss.  docs/cloth.md,
section "Measuring a swatch", gives the units, the noise model, the
uncertainties and the accuracy.

References
----------
.. [1] Yasuda, Yokoi, Toriwaki, Inagaki, "A shading model for cloth
   objects", IEEE Computer Graphics and Applications 12(6), 15-24 (1992),
   doi:10.1109/38.163621.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.cloth.swatch_geometry import SwatchGeometry, swatch_samples
from processing.errors import InputError

__all__ = [
    "FIT_PARAMETERS",
    "ClothFitError",
    "SwatchMeasurement",
    "ClothFit",
    "chart_gains",
    "grid_chart_means",
    "fit_material",
    "predict_rgb",
    "fit_swatch",
    "LAYER_CANDIDATES",
    "choose_layers",
]

#: Layer counts :func:`choose_layers` tries by default.
LAYER_CANDIDATES = (1, 2, 3, 4, 6, 8)

#: Names of the fitted parameters, in the order of the fit's vector.
FIT_PARAMETERS = ("a_t", "a_b", "specular", "internal", "diffuse", "dye_r", "dye_g", "dye_b")
_LOWER = np.array([2e-3, 2e-3, 0.0, 0.0, 0.0, 0.02, 0.02, 0.02])
_UPPER = np.array([3.0, 3.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
_CFA_OFFSETS = ((0, 0), (1, 0), (0, 1), (1, 1))      # (dx, dy) of the 2 x 2 cell in row order


class ClothFitError(InputError):
    """The swatch data cannot be fitted (too few pixels or frames, a bad chart); the message says why."""


@dataclass(frozen=True)
class SwatchMeasurement:
    """Camera responses of swatch pixels over table angles.

    Attributes
    ----------
    angles_deg
        ``(A,)`` table angles.
    pixels
        ``(P, 2)`` binned pixel (column, row); binned pixel (x, y) covers
        photosites (2x .. 2x+1, 2y .. 2y+1).
    rgb
        ``(A, P, 3)`` camera responses (RAW divided by the chart gains).
    cfa_pattern
        The 2 x 2 colour filter cell in row order, e.g. ``"RGGB"``.
    passes
        ``(A,)`` the pass (1-based) of each frame, i.e. which light of the set-up
        lit it (:meth:`processing.cloth.swatch_geometry.SwatchGeometry.for_pass`);
        default all 1.

    Raises
    ------
    ClothFitError
        Shapes that do not match, a CFA pattern that is not a 2 x 2 cell of
        R, G and B, or pass numbers that are not integers >= 1 per angle.
    """

    angles_deg: NDArray[np.float64]
    pixels: NDArray[np.int64]
    rgb: NDArray[np.float64]
    cfa_pattern: str = "RGGB"
    passes: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        a = np.asarray(self.angles_deg, dtype=np.float64).reshape(-1)
        px = np.asarray(self.pixels, dtype=np.int64).reshape(-1, 2)
        rgb = np.asarray(self.rgb, dtype=np.float64)
        if rgb.shape != (a.size, px.shape[0], 3):
            raise ClothFitError(f"rgb must have shape (angles {a.size}, pixels {px.shape[0]}, 3), got {rgb.shape}")
        cfa = str(self.cfa_pattern).upper()
        if len(cfa) != 4 or set(cfa) != {"R", "G", "B"}:
            raise ClothFitError(f"cfa_pattern must be a 2 x 2 cell such as 'RGGB', got {self.cfa_pattern!r}")
        passes = np.ones(a.size, np.int64) if self.passes is None else np.asarray(self.passes).reshape(-1)
        if passes.shape != a.shape or not np.issubdtype(passes.dtype, np.integer) or np.any(passes < 1):
            raise ClothFitError(f"passes must hold one pass number >= 1 per angle ({a.size}), got {self.passes!r}")
        object.__setattr__(self, "passes", passes.astype(np.int64))
        object.__setattr__(self, "angles_deg", a)
        object.__setattr__(self, "pixels", px)
        object.__setattr__(self, "rgb", rgb)
        object.__setattr__(self, "cfa_pattern", cfa)


@dataclass(frozen=True)
class ClothFit:
    """The fitted parameters and how well they explain the data.

    Attributes
    ----------
    parameters
        Fitted values by name (:data:`FIT_PARAMETERS`).
    sigma
        One-standard-deviation uncertainties by name.
    fixed
        The parameters held at the yarn preset's values.
    spec
        A material spec string of the fit (``kogei render --material ...``).
    residual_rms
        RMS of (predicted - measured) camera responses.
    relative_residual
        ``residual_rms`` over the mean measured response.
    predicted
        ``(A, P, 3)`` the model's responses at the measured pixels and angles.
    cost
        Final value of the robust cost.
    """

    parameters: dict[str, float]
    sigma: dict[str, float]
    fixed: dict[str, Any]
    spec: str
    residual_rms: float
    relative_residual: float
    predicted: NDArray[np.float64] = field(repr=False)
    cost: float = 0.0


def grid_chart_means(rgb: ArrayLike, rows: int = 4, columns: int = 6, inset: float = 0.3) -> NDArray[np.float64]:
    """Mean RGB of the patches of a chart filling the frame in a grid.

    Each patch is averaged over the middle ``1 - 2 inset`` of its cell (the
    station's ``grid`` chart layout; patches in reading order).

    Parameters
    ----------
    rgb
        ``(H, W, c)`` image of the chart.
    rows, columns
        Patches down and across.
    inset
        Fraction of a cell left out on each side.

    Returns
    -------
    ndarray
        ``(rows * columns, c)`` means, patches in reading order.

    Examples
    --------
    >>> img = np.repeat(np.arange(24.0).reshape(4, 6)[:, :, None], 3, axis=2).repeat(10, 0).repeat(10, 1)
    >>> grid_chart_means(img)[:3, 0].tolist()
    [0.0, 1.0, 2.0]
    """
    a = np.asarray(rgb, dtype=np.float64)
    h, w = a.shape[:2]
    out = np.empty((rows * columns, a.shape[2]))
    for r in range(rows):
        for c in range(columns):
            y0, y1 = int(round((r + inset) * h / rows)), int(round((r + 1 - inset) * h / rows))
            x0, x1 = int(round((c + inset) * w / columns)), int(round((c + 1 - inset) * w / columns))
            out[r * columns + c] = a[y0:max(y1, y0 + 1), x0:max(x1, x0 + 1)].reshape(-1, a.shape[2]).mean(axis=0)
    return out


def _spectral_setup(geometry: SwatchGeometry, step: float):
    from processing.camera.response import camera_sensitivities
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    grid = SpectralGrid(400.0, 700.0, step)
    return grid, light_spectrum(geometry.light, grid), camera_sensitivities(grid, geometry.camera)


def chart_gains(chart_means: ArrayLike, geometry: SwatchGeometry, step: float = 10.0) -> NDArray[np.float64]:
    """Per-channel gains: RAW means of the chart patches over their predicted camera responses.

    The patches' radiance is ``rho E / pi`` with rho the chart's reflectance
    spectra (colour-science) and E the light's relative spectrum; the gain is
    the least-squares ratio per channel.

    Parameters
    ----------
    chart_means
        ``(24, 3)`` RAW means of the patches in reading order.
    geometry
        Gives the chart, the light and the camera sensitivities.
    step
        Wavelength step (nm) of the prediction.

    Returns
    -------
    ndarray
        ``(3,)`` gains, RAW units per unit camera response.

    Raises
    ------
    ClothFitError
        An unknown chart, chart means of the wrong shape, or non-finite or
        non-positive gains (a dark, clipped or missing chart).
    """
    import colour

    from processing.camera.response import camera_rgb
    from processing.spectral.spectra import resample

    grid, e, sens = _spectral_setup(geometry, step)
    try:
        sds = colour.SDS_COLOURCHECKERS[geometry.chart]
    except KeyError:
        raise ClothFitError(f"unknown chart {geometry.chart!r} in the swatch geometry") from None
    refl = np.stack([resample(sd.wavelengths, sd.values, grid) for sd in sds.values()])
    pred = camera_rgb(refl / math.pi, e, sens, grid)
    meas = np.asarray(chart_means, dtype=np.float64)
    if meas.shape != pred.shape:
        raise ClothFitError(f"chart means must have shape {pred.shape}, got {meas.shape}")
    gains = np.sum(meas * pred, axis=0) / np.sum(pred * pred, axis=0)
    if not np.all(np.isfinite(gains)) or np.any(gains <= 0):
        raise ClothFitError(f"the chart frame gives no usable gains ({gains}); is the chart in the first frame?")
    return gains


def fit_material(values: ArrayLike, fixed: dict[str, Any]):
    """The cloth material of fitted values and the fixed parameters.

    Parameters
    ----------
    values
        Values in the order of :data:`FIT_PARAMETERS`; weights summing above
        1 are scaled back to 1 and the dye colour is clipped to [0, 1].
    fixed
        The parameters held at the yarn preset's values (:attr:`ClothFit.fixed`).

    Returns
    -------
    Material
        The cloth, named ``"swatch-fit"``, warp and weft alike.

    Raises
    ------
    ValueError
        Values the cloth builder refuses.
    """
    from processing.cloth.presets import build_cloth

    v = np.asarray(values, dtype=np.float64).copy()
    # weights summing above 1 are scaled back to 1 (the fit penalises the excess separately)
    v[2:5] /= max(1.0, float(np.sum(v[2:5])))
    rgb = tuple(float(x) for x in np.clip(v[5:8], 0.0, 1.0))
    params = dict(fixed)
    params.update(a_t=float(v[0]), a_b=float(v[1]), weft_a_t=float(v[0]), weft_a_b=float(v[1]),
                  specular=float(v[2]), internal=float(v[3]), diffuse=float(v[4]), warp_colour=rgb, weft_colour=rgb)
    return build_cloth("swatch-fit", params)


def predict_rgb(material, geometry: SwatchGeometry, angles_deg: ArrayLike, pixels: ArrayLike,
                cfa_pattern: str = "RGGB", step: float = 10.0, passes: ArrayLike | None = None) -> NDArray[np.float64]:
    """Camera responses of ``material`` at binned pixels over table angles.

    Each channel is the mean over the photosites of that colour in the
    pixel's 2 x 2 cell, as a ``bin2x2`` RAW decode forms it: per photosite
    ``sum f(lambda) cos_i E s_c`` with f the BRDF.

    Parameters
    ----------
    material
        The material (a cloth, or any material with a tangent frame).
    geometry
        The set-up.
    angles_deg
        ``(A,)`` table angles in degrees.
    pixels
        ``(P, 2)`` binned pixels (column, row).
    cfa_pattern
        The 2 x 2 colour filter cell in row order.
    step
        Wavelength step (nm) of the prediction.
    passes
        ``(A,)`` the pass (1-based) of each frame, which picks its light
        (default: pass 1 for all).

    Returns
    -------
    ndarray
        ``(A, P, 3)`` camera responses, in the units of
        :func:`processing.camera.response.camera_rgb`.

    Raises
    ------
    ClothFitError
        ``passes`` not one per angle, or a pass the set-up has no light for.
    """
    a = np.asarray(angles_deg, dtype=np.float64).reshape(-1)
    if passes is not None:
        p = np.asarray(passes, dtype=np.int64).reshape(-1)
        if p.shape != a.shape:
            raise ClothFitError(f"passes must hold one pass number per angle ({a.size}), got shape {p.shape}")
        if np.any(p != 1):
            px = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
            out = np.empty((a.size, px.shape[0], 3))
            for k in np.unique(p):
                try:
                    g = geometry.for_pass(int(k))
                except ValueError as exc:
                    raise ClothFitError(str(exc)) from None
                out[p == k] = predict_rgb(material, g, a[p == k], px, cfa_pattern, step)
            return out
    from processing.camera.response import camera_rgb
    from processing.materials.lobes import material_brdf

    grid, e, sens = _spectral_setup(geometry, step)
    px = np.asarray(pixels, dtype=np.int64).reshape(-1, 2)
    i = (2 * px[:, 0][:, None] + np.array([o[0] for o in _CFA_OFFSETS])[None, :]).ravel()
    j = (2 * px[:, 1][:, None] + np.array([o[1] for o in _CFA_OFFSETS])[None, :]).ravel()
    s = swatch_samples(geometry, a, i, j)
    f = material_brdf(material, s.cos_i, s.cos_o, s.cos_h, s.cos_d, grid.wavelengths, s.tangential)
    resp = camera_rgb(f * s.cos_i[..., None], e, sens, grid).reshape(a.size, px.shape[0], 4, 3)
    out = np.empty((a.size, px.shape[0], 3))
    for c, name in enumerate("RGB"):
        sites = [k for k, ch in enumerate(cfa_pattern.upper()) if ch == name]
        out[..., c] = resp[:, :, sites, c].mean(axis=2)
    return out


def fit_swatch(measurement: SwatchMeasurement, geometry: SwatchGeometry, *, yarn: str = "silk",
               layers: int | None = None, start: ArrayLike | None = None, step: float = 10.0,
               max_evaluations: int = 400) -> ClothFit:
    """Fit the cloth model to ``measurement`` by robust least squares.

    Parameters
    ----------
    measurement
        Camera responses of swatch pixels (:class:`SwatchMeasurement`).
    geometry
        The set-up.
    yarn
        Cloth preset whose non-fitted parameters are held (silk, cotton, satin).
    layers
        Internal layer count to hold (default: the preset's).
    start
        Initial values in the order of :data:`FIT_PARAMETERS` (default: the
        preset's axes and weights and a mid-grey dye).
    step
        Wavelength step (nm) of the model.
    max_evaluations
        Bound on model evaluations.

    Returns
    -------
    ClothFit
        Fitted values, one-sigma uncertainties, held parameters, a material
        spec, residuals and the predicted responses.

    Raises
    ------
    ClothFitError
        An unknown yarn, fewer than 3 angles or 8 pixels, frames of a pass
        the set-up has no light for, non-finite data, or black frames.

    References
    ----------
    .. [1] Yasuda et al. (1992), doi:10.1109/38.163621.
    """
    from processing.cloth.presets import CLOTH_PRESETS

    _check_measurement(measurement, geometry, yarn, CLOTH_PRESETS)
    fixed, x0 = _fixed_and_start(dict(CLOTH_PRESETS[yarn]), layers, start)
    result = _robust_fit(measurement, geometry, fixed, x0, step, max_evaluations)
    x = result.x.copy()
    if fixed["warp_fraction"] == 0.5 and x[0] > x[1]:
        x[[0, 1]] = x[[1, 0]]                   # plain weave of equal yarns: the axes are an unordered pair
    material = fit_material(x, fixed)
    meas = measurement.rgb
    pred = predict_rgb(material, geometry, measurement.angles_deg, measurement.pixels, measurement.cfa_pattern, step,
                       measurement.passes)
    sig = _parameter_sigma(result, fixed)
    rms = float(np.sqrt(np.mean((pred - meas) ** 2)))
    return ClothFit(dict(zip(FIT_PARAMETERS, map(float, x))), dict(zip(FIT_PARAMETERS, map(float, sig))), fixed,
                    _fit_spec(yarn, x, fixed), rms, rms / max(float(np.mean(np.abs(meas))), 1e-300), pred,
                    float(result.cost))


def _check_measurement(measurement: SwatchMeasurement, geometry: SwatchGeometry, yarn: str,
                       presets: Mapping[str, Any]) -> None:
    """Refuse an unknown yarn, too few angles or pixels, unknown passes and non-finite or black data."""
    if yarn not in presets:
        raise ClothFitError(f"unknown yarn preset {yarn!r}; use one of {', '.join(presets)}")
    if measurement.angles_deg.size < 3 or measurement.pixels.shape[0] < 8:
        raise ClothFitError(
            f"a swatch fit needs at least 3 table angles and 8 swatch pixels, got {measurement.angles_deg.size} "
            f"angles and {measurement.pixels.shape[0]} pixels"
        )
    if int(measurement.passes.max()) > geometry.passes:
        raise ClothFitError(
            f"the measurement has frames of pass {int(measurement.passes.max())} but the set-up gives "
            f"{geometry.passes} light direction(s); add pass_light_directions to the swatch geometry"
        )
    meas = measurement.rgb
    if not np.all(np.isfinite(meas)):
        raise ClothFitError("the swatch responses contain NaN or infinite values")
    if not float(np.mean(meas)) > 0:
        raise ClothFitError("the swatch frames are black (mean response <= 0): check the exposure and the light")


def _fixed_and_start(preset: dict[str, Any], layers: int | None,
                     start: ArrayLike | None) -> tuple[dict[str, Any], NDArray[np.float64]]:
    """The parameters held at the preset's values, and the start vector inside the bounds."""
    fixed = {k: preset[k] for k in ("warp_kind", "weft_kind", "warp_fraction", "layers", "rounding", "n", "scattering")}
    fixed["weft_kind"] = fixed["warp_kind"]
    if layers is not None:
        fixed["layers"] = int(layers)
    x0 = (np.asarray(start, dtype=np.float64) if start is not None else
          np.array([preset["a_t"], preset["a_b"], 0.8 * preset["specular"], 0.8 * preset["internal"],
                    0.8 * preset["diffuse"], 0.5, 0.5, 0.5]))
    x0 = np.clip(x0, _LOWER + 1e-9, _UPPER - 1e-9)
    return fixed, x0


def _robust_fit(measurement: SwatchMeasurement, geometry: SwatchGeometry, fixed: dict[str, Any],
                x0: NDArray[np.float64], step: float, max_evaluations: int) -> Any:
    """``scipy.optimize.least_squares`` (soft-L1) of the scaled residuals plus the energy penalty."""
    from scipy.optimize import least_squares

    meas = measurement.rgb
    scale = 0.01 * np.abs(meas) + 0.002 * float(np.mean(np.abs(meas)))

    def residual(x: NDArray[np.float64]) -> NDArray[np.float64]:
        try:
            pred = predict_rgb(fit_material(x, fixed), geometry, measurement.angles_deg, measurement.pixels,
                               measurement.cfa_pattern, step, measurement.passes)
        except ValueError:
            return np.full(meas.size + 1, 1e3)
        excess = max(0.0, float(np.sum(x[2:5])) - 1.0)     # energy: specular + internal + diffuse <= 1
        return np.append(((pred - meas) / scale).ravel(), 1e3 * excess)

    return least_squares(residual, x0, bounds=(_LOWER, _UPPER), loss="soft_l1", f_scale=3.0,
                         x_scale=np.array([0.05, 0.1, 0.05, 0.05, 0.05, 0.1, 0.1, 0.1]),
                         max_nfev=max_evaluations, diff_step=1e-4)


def _parameter_sigma(result: Any, fixed: dict[str, Any]) -> NDArray[np.float64]:
    """One-sigma uncertainties: the diagonal of ``s^2 (J^T J)^-1``, in the order of the reported values."""
    r = result.fun[:-1]
    dof = max(r.size - result.x.size, 1)
    jac = result.jac[:-1]
    if fixed["warp_fraction"] == 0.5 and result.x[0] > result.x[1]:
        jac = jac[:, [1, 0, 2, 3, 4, 5, 6, 7]]
    try:
        cov = np.linalg.pinv(jac.T @ jac) * float(np.sum(r * r) / dof)
        return np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        return np.full(result.x.size, np.nan)


def _fit_spec(yarn: str, x: NDArray[np.float64], fixed: dict[str, Any]) -> str:
    """The material spec string of fitted values ``x``."""
    hexa = "#" + "".join(f"{round(v * 255):02x}" for v in x[5:8])
    return (f"{yarn}:a_t={x[0]:.4g},a_b={x[1]:.4g},weft_a_t={x[0]:.4g},weft_a_b={x[1]:.4g},"
           f"specular={x[2]:.4g},internal={x[3]:.4g},diffuse={x[4]:.4g},layers={fixed['layers']},"
           f"warp_colour={hexa},weft_colour={hexa},weft_kind={fixed['weft_kind']}")


def choose_layers(measurement: SwatchMeasurement, geometry: SwatchGeometry, *, yarn: str = "silk",
                  candidates: tuple[int, ...] = LAYER_CANDIDATES, step: float = 10.0) -> tuple[ClothFit, dict[int, float]]:
    """Fit every layer count of ``candidates`` and keep the fit of lowest robust cost.

    Parameters
    ----------
    measurement, geometry, yarn, step
        As for :func:`fit_swatch`.
    candidates
        Layer counts to try, each in 0..50.

    Returns
    -------
    fit : ClothFit
        The fit of lowest robust cost.
    costs : dict of int to float
        The final robust cost of every candidate.

    Raises
    ------
    ClothFitError
        No candidates, a candidate outside 0..50, or an error of :func:`fit_swatch`.
    """
    if not candidates or any(not isinstance(k, (int, np.integer)) or not 0 <= k <= 50 for k in candidates):
        raise ClothFitError(f"layer candidates must be integers in 0..50, got {candidates!r}")
    fits = {int(k): fit_swatch(measurement, geometry, yarn=yarn, layers=int(k), step=step) for k in candidates}
    best = min(fits, key=lambda k: fits[k].cost)
    return fits[best], {k: f.cost for k, f in fits.items()}
