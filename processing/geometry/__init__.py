"""Geometry of a scanned object: calibration, point clouds, registration, surface and its checks.

Units are millimetres and degrees; the pipeline and its methods are described
in docs/processing.md.

Modules
-------
:mod:`~processing.geometry.calibration`
    The laser profiler's pose relative to the turntable axis, from a reference sphere.
:mod:`~processing.geometry.calibration_fit`
    Building blocks of that fit (table line, circles, closed-form start, least squares).
:mod:`~processing.geometry.scan_points`
    One pass's profiles -> oriented, confidence-weighted points in the table frame.
:mod:`~processing.geometry.registration`
    Registration of passes without an initial guess, verification, pose graph.
:mod:`~processing.geometry.fusion`
    Confidence-weighted fusion of an oriented cloud per voxel; spacing and noise.
:mod:`~processing.geometry.surface`
    Merged cloud -> watertight mesh with filled, reported holes (screened Poisson).
:mod:`~processing.geometry.surface_types`
    Presets and results of the surface stage.
:mod:`~processing.geometry.holes`
    Guide points on smooth surfaces fitted around the holes of a mesh.
:mod:`~processing.geometry.height_fields`
    The height fields fitted around a hole (sphere plus spline, spline, plane, floor).
:mod:`~processing.geometry.mesh_support`
    Where a mesh is supported by the data, and its unsupported regions.
:mod:`~processing.geometry.mesh_topology`
    Edges, boundaries, manifoldness and components of triangle meshes.
:mod:`~processing.geometry.mesh_ply`
    Binary PLY output of triangle meshes.
:mod:`~processing.geometry.surface_distance`
    Two-sided sampled distance between a reconstruction and the truth.
:mod:`~processing.geometry.camera_calibration`
    Camera intrinsics and pose relative to the turntable from ChArUco views; link to the room.

The functions :func:`~processing.geometry.mesh_support.mesh_support`,
:func:`~processing.geometry.mesh_topology.mesh_topology` and
:func:`~processing.geometry.surface_distance.surface_distance` share their
module's name, so they are imported from their modules, not from here.

References
----------
.. [1] Besl, P. J., McKay, N. D. (1992). A method for registration of 3-D
   shapes. IEEE TPAMI 14(2), 239-256. doi:10.1109/34.121791
.. [2] Chen, Y., Medioni, G. (1992). Object modelling by registration of
   multiple range images. Image and Vision Computing 10(3), 145-155.
   doi:10.1016/0262-8856(92)90066-C
.. [3] Rusinkiewicz, S., Levoy, M. (2001). Efficient variants of the ICP
   algorithm. 3DIM 2001. doi:10.1109/IM.2001.924423
.. [4] Kabsch, W. (1976). A solution for the best rotation to relate two sets
   of vectors. Acta Cryst. A32, 922-923. doi:10.1107/S0567739476001873
.. [5] Umeyama, S. (1991). Least-squares estimation of transformation
   parameters between two point patterns. IEEE TPAMI 13(4), 376-380.
   doi:10.1109/34.88573
.. [6] Rusu, R. B., Blodow, N., Beetz, M. (2009). Fast point feature
   histograms (FPFH) for 3D registration. ICRA 2009.
   doi:10.1109/ROBOT.2009.5152473
.. [7] Choi, S., Zhou, Q.-Y., Koltun, V. (2015). Robust reconstruction of
   indoor scenes. CVPR 2015. doi:10.1109/CVPR.2015.7299195
.. [8] Kazhdan, M., Hoppe, H. (2013). Screened Poisson surface
   reconstruction. ACM TOG 32(3), 29. doi:10.1145/2487228.2487237
.. [9] Pratt, V. (1987). Direct least-squares fitting of algebraic surfaces.
   SIGGRAPH 1987. doi:10.1145/37402.37420
.. [10] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura. CG
   reproduction of a craft object based on a light reflection model. IPSJ
   technical report.
"""

from processing.geometry.calibration import (
    CALIBRATION_SCHEMA,
    CALIBRATION_SCHEMA_VERSION,
    CalibrationError,
    ScannerCalibration,
    calibrate_sphere,
    check_sensor_to_room,
    ideal_sensor_to_room,
    profile_points_room,
)
from processing.geometry.fusion import (
    FusedCloud,
    dominated_samples,
    fuse_points,
    noise_level,
    point_spacing,
    validate_oriented_cloud,
)
from processing.geometry.holes import HoleFit, HoleGuides, hole_guide_points, inside_polygon
from processing.geometry.mesh_ply import write_mesh_ply
from processing.geometry.mesh_support import Hole, SupportReport, triangle_areas
from processing.geometry.mesh_topology import MeshTopology, boundary_edges, edge_twins, triangle_components
from processing.geometry.registration import (
    PRESETS,
    PairResult,
    PassPose,
    PoseGraphConsistency,
    RegistrationError,
    RegistrationPreset,
    RegistrationResult,
    merge_passes,
    pose_difference,
    register_from_picks,
    register_pair,
    register_passes,
    registration_preset,
    rigid_from_picks,
    rotation_samples,
    transform_points,
)
from processing.geometry.scan_points import ScanPoints, profiles_to_points
from processing.geometry.surface import SurfaceError, decimate_mesh, poisson_mesh, reconstruct_surface, vertex_normals
from processing.geometry.surface_distance import DistanceStats, SurfaceDistance, distance_to_mesh, sample_surface
from processing.geometry.surface_types import (
    SURFACE_PRESETS,
    FilledHole,
    SurfacePreset,
    SurfaceResult,
    SurfaceTimings,
)

__all__ = [
    # calibration
    "CALIBRATION_SCHEMA",
    "CALIBRATION_SCHEMA_VERSION",
    "CalibrationError",
    "ScannerCalibration",
    "calibrate_sphere",
    "check_sensor_to_room",
    "ideal_sensor_to_room",
    "profile_points_room",
    # scan_points
    "ScanPoints",
    "profiles_to_points",
    # registration
    "PRESETS",
    "PairResult",
    "PassPose",
    "PoseGraphConsistency",
    "RegistrationError",
    "RegistrationPreset",
    "RegistrationResult",
    "merge_passes",
    "pose_difference",
    "register_from_picks",
    "register_pair",
    "register_passes",
    "registration_preset",
    "rigid_from_picks",
    "rotation_samples",
    "transform_points",
    # fusion
    "FusedCloud",
    "dominated_samples",
    "fuse_points",
    "noise_level",
    "point_spacing",
    "validate_oriented_cloud",
    # surface
    "SURFACE_PRESETS",
    "FilledHole",
    "SurfaceError",
    "SurfacePreset",
    "SurfaceResult",
    "SurfaceTimings",
    "decimate_mesh",
    "poisson_mesh",
    "reconstruct_surface",
    "vertex_normals",
    # holes
    "HoleFit",
    "HoleGuides",
    "hole_guide_points",
    "inside_polygon",
    # mesh_support, mesh_topology, mesh_ply, surface_distance
    "Hole",
    "SupportReport",
    "triangle_areas",
    "MeshTopology",
    "boundary_edges",
    "edge_twins",
    "triangle_components",
    "write_mesh_ply",
    "DistanceStats",
    "SurfaceDistance",
    "distance_to_mesh",
    "sample_surface",
]
