"""kogei's pure computation, one subpackage per domain.

Subpackages
-----------
:mod:`processing.geometry`
    Scanner calibration, scan points, registration, fusion, surfaces, holes, meshes.
:mod:`processing.camera`
    RAW decoding, colour charts (layout, detection, sampling), camera response and transfer.
:mod:`processing.spectral`
    Wavelength grids and light spectra, display, reflectance databases, spectral estimation.
:mod:`processing.materials`
    Reflection models of metals, alloys and dielectrics, the preset registry, identification.
:mod:`processing.cloth`
    Woven cloth: the anisotropic model, presets, swatch geometry and fit.
:mod:`processing.common`
    Atomic files, PNG encoding, rotations: the helpers every layer above shares.
:mod:`processing.errors`
    :class:`~processing.errors.InputError`, the root of every input error.

Nothing here imports ``app``, ``drivers``, ``mocks``, ``render`` or Qt, and
``geometry`` is independent of the colour domains (docs/architecture.md).
"""
