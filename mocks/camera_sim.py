"""A simulated RAW camera: spectral radiance through real sensitivities to a noisy Bayer mosaic.

The image chain of a digital camera (e.g. EMVA Standard 1288, release 4.0,
section 2: linear signal model with shot noise, read noise and quantisation):

1. **Channel signal.**  For a pixel with spectral radiance ``L(lambda)`` the
   red, green and blue signals are ``integral L(lambda) s_c(lambda) dlambda``
   with the camera's spectral sensitivities ``s_c``; here the measured
   sensitivities of a Nikon D5100 (National Physical Laboratory, shipped by
   colour-science as ``MSDS_CAMERA_SENSITIVITIES['Nikon 5100 (NPL)']``),
   integrated on the spectral grid of the radiance (trapezoid weights = step).
2. **Lens.**  The lens and the optical low-pass (anti-aliasing) filter in
   front of the sensor spread a point over about one photosite: a Gaussian
   of ``LENS_SIGMA_PX`` photosites over the image plane (:func:`lens_blur`),
   applied to the radiance before the mosaic.  Without it a mirror-sharp
   highlight one photosite wide lights a single colour of its CFA cell
   (false colour that no demosaic can undo).
3. **Mosaic.**  Each photosite keeps one channel of its 2 x 2 CFA cell
   (``RGGB`` by default).
4. **Electrons.**  Mean electrons ``mu = signal * quantum_scale *
   exposure_s``; shot noise is Poisson(mu); read noise is Gaussian with
   ``read_noise_e`` electrons; the well clips at ``full_well_e``.
5. **Digital numbers.**  ``DN = round(e / gain_e_per_dn) + black_level``,
   clipped to ``[0, white_level]`` with ``white_level = 2**bits - 1``.

So the raw value of a uniform patch has mean ``black + mu / g`` and variance
``mu / g**2 + (read_noise_e / g)**2 + 1/12`` (DN^2) as long as nothing clips.

The DNG metadata comes from the same sensitivities: ColorMatrix1 (XYZ ->
camera under D65) is the least-squares fit of the 24 ColorChecker patches'
camera RGB against their XYZ, normalised so the D65 white maps to a maximum
channel of 1 (DNG 1.4, chapter 6); AsShotNeutral is the camera RGB of a
white diffuser under the scene light.

A saturation fault is an exposure multiplier (``exposure_boost``), which
drives bright pixels into the white level as an over-exposed shot would.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.camera.response import CameraResponseError
from processing.camera.response import camera_sensitivities as _camera_sensitivities
from processing.errors import InputError
from processing.spectral.spectra import SpectralGrid, resample

__all__ = [
    "SENSITIVITIES",
    "LENS_SIGMA_PX",
    "SensorModel",
    "RawFrame",
    "CameraSimError",
    "camera_sensitivities",
    "channel_signal",
    "lens_blur",
    "mosaic",
    "expose",
    "xyz_to_camera_matrix",
    "white_balance_neutral",
    "simulate_raw",
    "write_raw",
]

#: Default camera of the simulation (a key of ``colour.MSDS_CAMERA_SENSITIVITIES``).
SENSITIVITIES = "Nikon 5100 (NPL)"

#: Standard deviation (photosites) of the simulated lens and optical low-pass filter's point spread.
LENS_SIGMA_PX = 1.0

_CFA_INDEX = {"R": 0, "G": 1, "B": 2}


class CameraSimError(InputError):
    """An input of the camera simulation is not valid; the message names it."""


@dataclass(frozen=True)
class SensorModel:
    """Parameters of the simulated sensor.

    Attributes
    ----------
    sensitivities
        Name of the camera in ``colour.MSDS_CAMERA_SENSITIVITIES``.
    bits
        ADC resolution (12 or 14).
    black_level
        Offset added to every photosite (DN).
    gain_e_per_dn
        Electrons per digital number (> 0).
    read_noise_e
        Standard deviation of the read noise (electrons, >= 0).
    quantum_scale
        Electrons per second per unit of channel signal (radiance x
        sensitivity x nm).  With the world's light scaled so a white
        diffuser has luminance Y = 1 (:mod:`mocks.world`), the default puts
        a white diffuser's green channel at about 70 % of the well at
        0.01 s.
    full_well_e
        Well capacity (electrons); None: what the ADC range can hold.
    cfa_pattern
        The 2 x 2 colour filter cell in row order.
    iso
        ISO speed written to the file.
    make, model
        Written to the DNG.
    """

    sensitivities: str = SENSITIVITIES
    bits: int = 14
    black_level: int = 600
    gain_e_per_dn: float = 2.0
    read_noise_e: float = 4.0
    quantum_scale: float = 2.2e6
    full_well_e: float | None = None
    cfa_pattern: str = "RGGB"
    iso: int = 100
    make: str = "Nikon"
    model: str = "D5100 (simulated)"

    def __post_init__(self) -> None:
        if self.bits not in (12, 14, 16):
            raise CameraSimError(f"SensorModel bits must be 12, 14 or 16, got {self.bits!r}")
        if not 0 <= int(self.black_level) < self.white_level:
            raise CameraSimError(
                f"SensorModel black_level must be in [0, {self.white_level}) DN for {self.bits} bits, "
                f"got {self.black_level!r}"
            )
        for name in ("gain_e_per_dn", "quantum_scale"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise CameraSimError(f"SensorModel {name} must be > 0, got {v!r}")
        if not (np.isfinite(self.read_noise_e) and self.read_noise_e >= 0):
            raise CameraSimError(f"SensorModel read_noise_e must be >= 0 electrons, got {self.read_noise_e!r}")
        if self.full_well_e is not None and not (np.isfinite(self.full_well_e) and self.full_well_e > 0):
            raise CameraSimError(f"SensorModel full_well_e must be > 0 electrons or None, got {self.full_well_e!r}")
        p = str(self.cfa_pattern).upper()
        if len(p) != 4 or set(p) != {"R", "G", "B"}:
            raise CameraSimError(f"SensorModel cfa_pattern must be like 'RGGB', got {self.cfa_pattern!r}")

    @property
    def white_level(self) -> int:
        """Largest raw value, ``2**bits - 1`` (DN)."""
        return (1 << self.bits) - 1

    @property
    def well_e(self) -> float:
        """Effective well capacity in electrons."""
        adc = (self.white_level - self.black_level) * self.gain_e_per_dn
        return float(adc if self.full_well_e is None else self.full_well_e)


@dataclass
class RawFrame:
    """A simulated RAW capture and the metadata its DNG needs.

    Attributes
    ----------
    bayer
        ``(H, W)`` uint16 mosaic in DN.
    black_level, white_level
        DN.
    cfa_pattern
        The 2 x 2 cell in row order.
    exposure_time
        Seconds.
    iso
        ISO speed.
    color_matrix
        ColorMatrix1, XYZ -> camera under D65.
    as_shot_neutral
        Camera RGB of the scene white (max 1).
    mean_electrons
        ``(H, W)`` expected electrons before noise (for checks).
    make, model
        Camera identification.
    f_number
        The aperture written to the DNG (None: not recorded).
    """

    bayer: NDArray[np.uint16]
    black_level: int
    white_level: int
    cfa_pattern: str
    exposure_time: float
    iso: int
    color_matrix: NDArray[np.float64]
    as_shot_neutral: NDArray[np.float64]
    mean_electrons: NDArray[np.float64] = field(repr=False)
    make: str = "Nikon"
    model: str = "D5100 (simulated)"
    f_number: float | None = None


def camera_sensitivities(grid: SpectralGrid, name: str = SENSITIVITIES) -> NDArray[np.float64]:
    """Spectral sensitivities ``(L, 3)`` (R, G, B) of camera ``name`` on ``grid`` (linear interpolation).

    Loaded by :func:`processing.camera.response.camera_sensitivities`.

    Examples
    --------
    >>> s = camera_sensitivities(SpectralGrid(400, 700, 10))
    >>> s.shape, int(np.argmax(s[:, 1]) * 10 + 400) in range(510, 560)
    ((31, 3), True)
    """
    try:
        return _camera_sensitivities(grid, name)
    except CameraResponseError as exc:
        raise CameraSimError(str(exc)) from None


def channel_signal(radiance: ArrayLike, grid: SpectralGrid, name: str = SENSITIVITIES) -> NDArray[np.float64]:
    """Camera R, G, B signals ``(..., 3)`` of spectral radiance ``(..., L)``: ``sum L s_c step``.

    Examples
    --------
    >>> g = SpectralGrid(400, 700, 10)
    >>> rgb = channel_signal(np.ones(g.size), g)
    >>> bool(np.all(rgb > 0))
    True
    """
    s = camera_sensitivities(grid, name)
    rad = np.asarray(radiance)
    if rad.ndim == 0 or rad.shape[-1] != grid.size:
        raise CameraSimError(
            f"radiance must have the {grid.size} wavelengths of the grid on its last axis, got shape {rad.shape}"
        )
    if not np.all(np.isfinite(rad)) or np.any(rad < 0):
        raise CameraSimError("radiance must be finite and >= 0 (spectral radiance)")
    return rad.astype(np.float64, copy=False) @ (s * grid.step)


#: The most channels OpenCV filters in one image (``CV_CN_MAX``); more go through SciPy.
_CV_MAX_CHANNELS = 512


def lens_blur(radiance: ArrayLike, sigma_px: float = LENS_SIGMA_PX) -> NDArray[np.float64]:
    """The lens and optical low-pass filter: a Gaussian of ``sigma_px`` photosites over the image plane.

    Parameters
    ----------
    radiance
        ``(H, W)`` or ``(H, W, L)`` image (spectral or channel values); the
        blur acts on the first two axes only.
    sigma_px
        Standard deviation of the point spread (photosites); 0 leaves the
        image as it is (a pinhole).

    Returns
    -------
    numpy.ndarray
        The blurred image (edges extended by their nearest pixel), same shape.

    Examples
    --------
    >>> img = np.zeros((9, 9, 1)); img[4, 4] = 1.0
    >>> out = lens_blur(img, 1.0)
    >>> round(float(out.sum()), 6), round(float(out[4, 4, 0]), 3)
    (1.0, 0.159)
    """
    import cv2
    from scipy.ndimage import gaussian_filter

    img = np.asarray(radiance, dtype=np.float64)
    if not (np.isfinite(sigma_px) and sigma_px >= 0):
        raise CameraSimError(f"lens sigma_px must be a finite number >= 0 photosites, got {sigma_px!r}")
    if img.ndim not in (2, 3):
        raise CameraSimError(f"lens_blur needs an (H, W) or (H, W, L) image, got shape {img.shape}")
    if sigma_px == 0 or img.size == 0:
        return img.copy()
    channels = 1 if img.ndim == 2 else img.shape[2]
    if channels > _CV_MAX_CHANNELS:
        return gaussian_filter(img, sigma=(sigma_px, sigma_px) + (0.0,) * (img.ndim - 2), mode="nearest")
    # SciPy's kernel (radius 4 sigma), applied by OpenCV's separable filter: the same sums over the image
    # plane (to rounding), three times faster on a spectral frame, whose channels OpenCV filters together
    radius = int(4.0 * sigma_px + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (x / sigma_px) ** 2)
    kernel /= kernel.sum()
    out = cv2.sepFilter2D(np.ascontiguousarray(img), cv2.CV_64F, kernel, kernel, borderType=cv2.BORDER_REPLICATE)
    return out.reshape(img.shape)


def mosaic(rgb: ArrayLike, pattern: str = "RGGB") -> NDArray[np.float64]:
    """Keep one channel per photosite: ``(H, W, 3)`` -> ``(H, W)`` by the 2 x 2 CFA ``pattern``.

    Examples
    --------
    >>> img = np.zeros((2, 2, 3)); img[..., 0] = 1; img[..., 1] = 2; img[..., 2] = 3
    >>> mosaic(img, "RGGB").tolist()
    [[1.0, 2.0], [2.0, 3.0]]
    """
    a = np.asarray(rgb, dtype=np.float64)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] % 2 or a.shape[1] % 2:
        raise CameraSimError(f"rgb must be (H, W, 3) with even H and W, got shape {a.shape}")
    p = pattern.upper()
    if len(p) != 4 or set(p) != {"R", "G", "B"}:
        raise CameraSimError(f"pattern must be a 2 x 2 CFA such as 'RGGB', got {pattern!r}")
    idx = np.empty(a.shape[:2], dtype=np.intp)
    for k, c in enumerate(p):
        idx[k // 2::2, k % 2::2] = _CFA_INDEX[c]
    return np.take_along_axis(a, idx[..., None], axis=2)[..., 0]


def expose(
    signal: ArrayLike,
    sensor: SensorModel,
    exposure_s: float,
    rng: np.random.Generator,
    *,
    exposure_boost: float = 1.0,
) -> tuple[NDArray[np.uint16], NDArray[np.float64]]:
    """Turn a mosaic of channel signals into raw DN with shot and read noise.

    Parameters
    ----------
    signal
        ``(H, W)`` channel signal per photosite (radiance x sensitivity x nm).
    sensor
        The sensor model.
    exposure_s
        Exposure time in seconds (> 0).
    rng
        Random generator (seeded for reproducible frames).
    exposure_boost
        Multiplier of the exposure (>= 1 over-exposes: the saturation fault).

    Returns
    -------
    bayer, mean_electrons
        uint16 ``(H, W)`` DN and the expected electrons before noise.

    Examples
    --------
    >>> dn, mu = expose(np.full((2, 2), 1.0), SensorModel(read_noise_e=0.0), 0.01, np.random.default_rng(0))
    >>> float(mu[0, 0]), dn.dtype.name
    (22000.0, 'uint16')
    """
    sig = np.asarray(signal, dtype=np.float64)
    if sig.ndim != 2 or not np.all(np.isfinite(sig)) or np.any(sig < 0):
        raise CameraSimError("signal must be a finite, non-negative (H, W) mosaic")
    if not (np.isfinite(exposure_s) and exposure_s > 0):
        raise CameraSimError(f"exposure_s must be > 0 seconds, got {exposure_s!r}")
    if not (np.isfinite(exposure_boost) and exposure_boost > 0):
        raise CameraSimError(f"exposure_boost must be > 0, got {exposure_boost!r}")
    mu = sig * (sensor.quantum_scale * exposure_s * exposure_boost)
    if np.any(mu > 1e15):
        raise CameraSimError("the expected electron count exceeds 1e15; lower exposure_s or the radiance scale")
    electrons = rng.poisson(mu).astype(np.float64)
    if sensor.read_noise_e > 0:
        electrons += rng.normal(0.0, sensor.read_noise_e, size=mu.shape)
    np.clip(electrons, None, sensor.well_e, out=electrons)
    dn = np.rint(electrons / sensor.gain_e_per_dn) + sensor.black_level
    np.clip(dn, 0, sensor.white_level, out=dn)
    return dn.astype(np.uint16), mu


@functools.lru_cache(maxsize=8)
def _matrix_cached(name: str, start: float, stop: float, step: float) -> NDArray[np.float64]:
    import colour

    from processing.spectral.display import spectra_to_xyz
    from processing.spectral.spectra import light_spectrum

    grid = SpectralGrid(start, stop, step)
    chart = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    refl = np.stack([resample(sd.wavelengths, sd.values, grid) for sd in chart.values()])
    e = light_spectrum("D65", grid)
    xyz = spectra_to_xyz(refl * e, grid)
    cam = channel_signal(refl * e, grid, name)
    m = np.linalg.lstsq(xyz, cam, rcond=None)[0].T            # cam = M xyz
    white = e / np.pi
    xyz_w = spectra_to_xyz(white, grid)
    m = m / np.max(m @ (xyz_w / xyz_w[1]))
    m.setflags(write=False)
    return m


def xyz_to_camera_matrix(grid: SpectralGrid, name: str = SENSITIVITIES) -> NDArray[np.float64]:
    """DNG ColorMatrix1 (XYZ -> camera RGB under D65) fitted on the 24 ColorChecker patches.

    Normalised so the D65 white (Y = 1) maps to a largest camera channel of 1.

    Examples
    --------
    >>> m = xyz_to_camera_matrix(SpectralGrid(400, 700, 10))
    >>> m.shape
    (3, 3)
    """
    return _matrix_cached(name, grid.start, grid.stop, grid.step)


def white_balance_neutral(light: ArrayLike, grid: SpectralGrid, name: str = SENSITIVITIES) -> NDArray[np.float64]:
    """Camera RGB of a white diffuser under ``light`` scaled to a largest channel of 1 (AsShotNeutral).

    Examples
    --------
    >>> from processing.spectral.spectra import light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> n = white_balance_neutral(light_spectrum("A", g), g)
    >>> bool(n[0] > n[2])      # incandescent light: red above blue
    True
    """
    rgb = channel_signal(np.asarray(light, dtype=np.float64), grid, name)
    if not np.all(rgb > 0):
        raise CameraSimError("the light gives no signal in some camera channel; check the light spectrum")
    return rgb / rgb.max()


def simulate_raw(
    radiance: ArrayLike,
    grid: SpectralGrid,
    light: ArrayLike,
    *,
    sensor: SensorModel = SensorModel(),
    exposure_s: float = 0.01,
    seed: int | None = 0,
    exposure_boost: float = 1.0,
) -> RawFrame:
    """Simulate one RAW capture of a spectral radiance image.

    Parameters
    ----------
    radiance
        ``(H, W, L)`` spectral radiance on ``grid`` (H, W even).
    grid
        Its wavelength grid (within 380-780 nm for the Nikon sensitivities).
    light
        ``(L,)`` spectrum of the scene light (for AsShotNeutral).
    sensor
        The sensor model.
    exposure_s
        Exposure time (s).
    seed
        Seed of the noise (None: fresh noise).
    exposure_boost
        Exposure multiplier of the saturation fault (1: none).

    Returns
    -------
    RawFrame

    Examples
    --------
    >>> g = SpectralGrid(400, 700, 20)
    >>> f = simulate_raw(np.full((4, 4, g.size), 0.01), g, np.ones(g.size))
    >>> f.bayer.shape, f.white_level
    ((4, 4), 16383)
    """
    rad = np.asarray(radiance)
    if rad.ndim != 3:
        raise CameraSimError(f"radiance must be (H, W, L), got shape {rad.shape}")
    rgb = channel_signal(rad, grid, sensor.sensitivities)
    signal = mosaic(rgb, sensor.cfa_pattern)
    rng = np.random.default_rng(seed)
    bayer, mu = expose(signal, sensor, exposure_s, rng, exposure_boost=exposure_boost)
    return RawFrame(
        bayer=bayer,
        black_level=int(sensor.black_level),
        white_level=sensor.white_level,
        cfa_pattern=sensor.cfa_pattern.upper(),
        exposure_time=float(exposure_s),
        iso=int(sensor.iso),
        color_matrix=np.array(xyz_to_camera_matrix(grid, sensor.sensitivities)),
        as_shot_neutral=white_balance_neutral(light, grid, sensor.sensitivities),
        mean_electrons=mu,
        make=sensor.make,
        model=sensor.model,
    )


def write_raw(path: str | os.PathLike[str], frame: RawFrame) -> Path:
    """Write a :class:`RawFrame` as a DNG with :func:`mocks.dng_writer.write_dng` (atomically).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> g = SpectralGrid(400, 700, 20)
    >>> f = simulate_raw(np.full((24, 24, g.size), 0.01), g, np.ones(g.size))
    >>> write_raw(pathlib.Path(tempfile.mkdtemp()) / "f.dng", f).suffix
    '.dng'
    """
    from mocks.dng_writer import write_dng

    return write_dng(
        path,
        frame.bayer,
        black_level=frame.black_level,
        white_level=frame.white_level,
        cfa_pattern=frame.cfa_pattern,
        color_matrix=frame.color_matrix,
        calibration_illuminant="D65",
        as_shot_neutral=frame.as_shot_neutral,
        exposure_time=frame.exposure_time,
        iso=frame.iso,
        make=frame.make,
        model=frame.model,
        f_number=frame.f_number,
    )
