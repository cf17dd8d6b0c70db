"""Spectral: wavelength grids, light spectra, display colour, reflectance databases and spectral estimation.

Modules
-------
spectra
    Wavelength grids, CIE colour-matching functions, light spectra and resampling.
display
    From spectra to display colour: XYZ, white normalisation, sRGB, gamut policy, CIEDE2000.
reflectance_database
    Training and chart reflectances, user CSV files, near-duplicate removal.
tables
    Reading a CSV table of values against wavelength, with errors that name the line.
checks
    The input checks and the error shared by camera calibration and spectral estimation.
estimation
    Subpackage: spectral estimation from camera values (its own front door,
    :mod:`processing.spectral.estimation`, since it builds on
    :mod:`processing.camera`, which builds on the modules above).

docs/materials.md ("From spectra to the display") and docs/colour-pipeline.md
describe them.

References
----------
CIE 015:2018 Colorimetry, 4th edition. doi:10.25039/TR.015.2018

IEC 61966-2-1:1999, Multimedia systems and equipment -- Colour measurement and
management -- Default RGB colour space -- sRGB (no DOI).
"""

from processing.spectral.checks import SpectralEstimationError, checked_channels, checked_spectra
from processing.spectral.display import (
    GAMUT_POLICIES,
    SRGB_LUMINANCE,
    adaptation_methods,
    delta_e00,
    encode_srgb8,
    gamut_map,
    spectra_to_xyz,
    white_xyz,
    xyz_scale,
    xyz_to_linear_srgb,
    xyz_to_srgb8,
)
from processing.spectral.reflectance_database import (
    DUPLICATE_RMSE,
    ReflectanceDatabaseError,
    ReflectanceSet,
    combine,
    database_names,
    load_reflectances,
    near_duplicates,
    read_reflectance_csv,
    without_near_duplicates,
)
from processing.spectral.spectra import (
    CMF_RANGE,
    REFERENCE_GRID,
    SpectralGrid,
    cmfs,
    illuminant_names,
    light_spectrum,
    resample,
)
from processing.spectral.tables import WavelengthTable, read_wavelength_table

__all__ = [
    # spectra
    "SpectralGrid",
    "REFERENCE_GRID",
    "CMF_RANGE",
    "cmfs",
    "light_spectrum",
    "resample",
    "illuminant_names",
    # display
    "spectra_to_xyz",
    "xyz_scale",
    "white_xyz",
    "xyz_to_linear_srgb",
    "gamut_map",
    "encode_srgb8",
    "xyz_to_srgb8",
    "delta_e00",
    "GAMUT_POLICIES",
    "SRGB_LUMINANCE",
    "adaptation_methods",
    # reflectance_database
    "DUPLICATE_RMSE",
    "ReflectanceDatabaseError",
    "ReflectanceSet",
    "database_names",
    "load_reflectances",
    "read_reflectance_csv",
    "near_duplicates",
    "without_near_duplicates",
    "combine",
    # tables
    "WavelengthTable",
    "read_wavelength_table",
    # checks
    "SpectralEstimationError",
    "checked_channels",
    "checked_spectra",
]
