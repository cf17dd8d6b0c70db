"""Registration of scan passes: global search, coarse-to-fine ICP, verification, pose graph.

Between passes the object is re-placed by hand, so the rigid motion between
two passes is unknown and may be any rotation, and each pass is a partial
view.  Every pair is registered without an initial guess and verified; a
pose graph then maps every pass into the frame of pass 0.  The method is
described in docs/processing.md, section "Registration of passes".  Units
are millimetres; a transform ``T`` (4 x 4) of a pair maps points of its
*source* cloud into the frame of its *target* cloud: ``x_t = T @ x_s``.

Modules
-------
:mod:`~processing.geometry.registration.presets`
    Speed / accuracy presets and :class:`RegistrationError`.
:mod:`~processing.geometry.registration.results`
    The results of a pair, of a pass's pose, of the pose graph, of several passes.
:mod:`~processing.geometry.registration.transforms`
    Rotations spread over SO(3), applying and comparing transforms, Kabsch fit of picks.
:mod:`~processing.geometry.registration.clouds`
    Validated clouds and their voxel pyramids (normals, roughness, lookup grids).
:mod:`~processing.geometry.registration.global_search`
    Batched point-to-plane ICP from many starting rotations (and FPFH + RANSAC).
:mod:`~processing.geometry.registration.refinement`
    Point-to-plane ICP over a voxel pyramid, the fit in both directions, the verdict.
:mod:`~processing.geometry.registration.symmetry`
    Weak directions of a fit, sweeps about a weak axis, margins and evidence over competing poses.
:mod:`~processing.geometry.registration.pose_evidence`
    Evidence for one pose over another where they differ, against the range noise.
:mod:`~processing.geometry.registration.pairwise`
    :func:`register_pair` and :func:`register_from_picks`.
:mod:`~processing.geometry.registration.pose_graph`
    :func:`register_passes` (every pair, then the pose graph) and :func:`merge_passes`.

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
.. [8] Alexa, M. (2022). Super-Fibonacci spirals: fast, low-discrepancy
   sampling of SO(3). CVPR 2022.
.. [9] Gelfand, N., Ikemoto, L., Rusinkiewicz, S., Levoy, M. (2003).
   Geometrically stable sampling for the ICP algorithm. 3DIM 2003.
"""

from processing.geometry.registration.clouds import MIN_POINTS
from processing.geometry.registration.pairwise import register_from_picks, register_pair
from processing.geometry.registration.photo_consistency import PointColours
from processing.geometry.registration.pose_graph import merge_passes, register_passes
from processing.geometry.registration.presets import (
    PRESETS,
    RegistrationError,
    RegistrationPreset,
    registration_preset,
)
from processing.geometry.registration.results import (
    PairResult,
    PassPose,
    PoseGraphConsistency,
    RegistrationResult,
)
from processing.geometry.registration.transforms import (
    pose_difference,
    rigid_from_picks,
    rotation_samples,
    transform_points,
)

__all__ = [
    "MIN_POINTS",
    "PRESETS",
    "PairResult",
    "PassPose",
    "PointColours",
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
]
