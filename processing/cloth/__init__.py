"""Woven cloth: the anisotropic reflection model of Yasuda et al., its presets and a swatch fit.

Modules
-------
- ``anisotropic_microfacet``: the yarn ellipsoid as a normalised anisotropic microfacet lobe.
- ``model``: warp and weft yarns, dyes, internal layers and the cloth material.
- ``presets``: silk, cotton, tamamushi and satin.
- ``anisotropic_albedo``: directional albedo of anisotropic lobes and cloth materials.
- ``draped``: a draped sheet with sinusoidal folds and UVs along warp and weft.
- ``swatch_geometry``: camera, light and tangent frame of a swatch on the turntable.
- ``fit``: the cloth model fitted to RAW frames of a swatch.

docs/cloth.md describes the model, the rendering, the figures and the swatch fit.

References
----------
.. [1] Yasuda, Yokoi, Toriwaki, Inagaki, "A shading model for cloth
   objects", IEEE Computer Graphics and Applications 12(6), 15-24 (1992),
   doi:10.1109/38.163621.
.. [2] Kubelka & Munk, "Ein Beitrag zur Optik der Farbanstriche",
   Zeitschrift fur technische Physik 12, 593-601 (1931) (no DOI).
.. [3] Smith, "Geometrical shadowing of a random rough surface", IEEE
   Transactions on Antennas and Propagation 15(5), 668-671 (1967),
   doi:10.1109/TAP.1967.1138991.
.. [4] Heitz, "Understanding the masking-shadowing function in
   microfacet-based BRDFs", Journal of Computer Graphics Techniques 3(2),
   48-107 (2014).
.. [5] Mallett & Yuksel, "Spectral primary decomposition for rendering
   with sRGB reflectance", EGSR 2019, doi:10.2312/SR.20191216.
"""

from processing.cloth.anisotropic_albedo import anisotropic_lobe_albedo, azimuth_mean_albedo, material_albedo
from processing.cloth.anisotropic_microfacet import (
    AXIS_RANGE,
    anisotropic_lobe,
    check_axes,
    ellipsoid_distance,
    ellipsoid_ndf,
    smith_lambda,
)
from processing.cloth.draped import DrapedCloth, draped_cloth
from processing.cloth.fit import (
    FIT_PARAMETERS,
    LAYER_CANDIDATES,
    ClothFit,
    ClothFitError,
    SwatchMeasurement,
    chart_gains,
    choose_layers,
    fit_material,
    fit_swatch,
    grid_chart_means,
    predict_rgb,
)
from processing.cloth.model import (
    FIBRE_INDEX,
    MAX_LAYERS,
    Dye,
    InternalLayerReflectance,
    Yarn,
    cloth_material,
    kubelka_munk_ratio,
    kubelka_munk_reflectance,
    layer_axes,
    layer_normaliser,
    parse_colour,
)
from processing.cloth.presets import CLOTH_PARAMETERS, CLOTH_PRESETS, CLOTH_SOURCES, build_cloth
from processing.cloth.swatch_geometry import SwatchGeometry, SwatchGeometryError, SwatchSamples, swatch_samples

__all__ = [
    # anisotropic_microfacet
    "ellipsoid_distance", "ellipsoid_ndf", "smith_lambda", "anisotropic_lobe", "check_axes", "AXIS_RANGE",
    # model
    "FIBRE_INDEX", "MAX_LAYERS", "Dye", "Yarn", "InternalLayerReflectance", "kubelka_munk_reflectance",
    "kubelka_munk_ratio", "layer_axes", "layer_normaliser", "parse_colour", "cloth_material",
    # presets
    "CLOTH_PRESETS", "CLOTH_PARAMETERS", "CLOTH_SOURCES", "build_cloth",
    # anisotropic_albedo
    "anisotropic_lobe_albedo", "material_albedo", "azimuth_mean_albedo",
    # draped
    "DrapedCloth", "draped_cloth",
    # swatch_geometry
    "SwatchGeometry", "SwatchSamples", "swatch_samples", "SwatchGeometryError",
    # fit
    "FIT_PARAMETERS", "ClothFitError", "SwatchMeasurement", "ClothFit", "chart_gains", "grid_chart_means",
    "fit_material", "predict_rgb", "fit_swatch", "LAYER_CANDIDATES", "choose_layers",
]
