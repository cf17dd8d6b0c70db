"""Lighting: measured and analytic light around the table, as spectral environment maps.

Modules
-------
environment_map
    :class:`~processing.lighting.environment_map.EnvironmentMap` (equirectangular
    spectral-basis radiance in the table frame), reading and writing ``.exr`` /
    ``.hdr`` files, sRGB upsampling by Mallett and Yuksel (2019).
hdr_merge
    Exposure brackets of RAW frames merged into linear HDR camera RGB
    (colour-hdri's weighting, exposures from the files' metadata).
probe_unwrap
    A mirror sphere's HDR photo unwrapped into an equirectangular map in the
    room frame with the calibrated camera; the unseen caps marked and filled.
probe_spectral
    The probe's camera RGB made spectral by the chart-calibrated estimator;
    two bracket sets (the second through a colour filter) as six channels.
nmf_lee2001
    A few non-negative basis spectra that a map's spectra mix (Lee and Seung's
    non-negative matrix factorisation), colour kept first.
daylight_sky
    :func:`~processing.lighting.daylight_sky.daylight_sky`: an outdoor sky
    (CIE general sky luminance, CIE daylight spectra, a sun disc, a ground).

docs/lighting.md describes the frame, the units, the file format and the light probe.

References
----------
Mallett, I., & Yuksel, C. (2019). Spectral Primary Decomposition for
Rendering with sRGB Reflectance. doi:10.2312/sr.20191216

Debevec, P. E., & Malik, J. (1997). Recovering high dynamic range radiance
maps from photographs. SIGGRAPH 97. doi:10.1145/258734.258884
"""

from processing.lighting.environment_map import (
    HEADER_KEY,
    EnvironmentMap,
    EnvironmentMapError,
    direction_pixels,
    pixel_directions,
    read_environment,
    srgb_basis,
    uniform_environment,
    write_environment,
)
from processing.lighting.hdr_merge import HdrImage, HdrMergeError, exposure_scale, merge_brackets
from processing.lighting.nmf_lee2001 import NonnegativeBasisError, nonnegative_basis, nonnegative_coefficients
from processing.lighting.probe_spectral import ProbeSpectralError, probe_environment, two_set_environment
from processing.lighting.probe_unwrap import ProbeUnwrap, ProbeUnwrapError, unwrap_probe

__all__ = [
    "HEADER_KEY",
    "EnvironmentMap",
    "EnvironmentMapError",
    "direction_pixels",
    "pixel_directions",
    "read_environment",
    "srgb_basis",
    "uniform_environment",
    "write_environment",
    "HdrImage",
    "HdrMergeError",
    "exposure_scale",
    "merge_brackets",
    "ProbeSpectralError",
    "probe_environment",
    "two_set_environment",
    "NonnegativeBasisError",
    "nonnegative_basis",
    "nonnegative_coefficients",
    "ProbeUnwrap",
    "ProbeUnwrapError",
    "unwrap_probe",
]
