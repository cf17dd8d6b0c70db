"""Registration of scan passes: global search, coarse-to-fine ICP, pose graph, verification.

Issue #4, "Registration of passes".  Between passes the object is re-placed
by hand, so the rigid motion between two passes is unknown and may be any
rotation; each pass is a partial view (the underside against the table and
self-occluded parts are missing), and craft objects are often smooth and
nearly symmetric, where feature matching (FPFH + RANSAC, Rusu et al. 2009)
alone fails.  The method here:

1. **Global search** (no initial guess).  A few hundred to a few thousand
   rotations from a super-Fibonacci spiral (Alexa, "Super-Fibonacci Spirals:
   Fast, Low-Discrepancy Sampling of SO(3)", CVPR 2022), plus the identity
   and optionally the FPFH + RANSAC estimate, each with the centroids
   aligned, run a cheap point-to-plane ICP (Chen & Medioni 1992) *all at
   once* (batched NumPy, nearest neighbours from a lookup grid) on heavily
   downsampled clouds with a shrinking correspondence distance, pruned by
   successive halving.  Candidates are ranked by a truncated quadratic score
   ``sum_i max(0, 1 - (r_i / s)^2) / N`` of the point-to-plane residuals
   ``r_i``, which ignores points outside the overlap (partial views).
2. **Refinement.**  The best few *distinct* hypotheses are refined by
   point-to-plane ICP with Tukey's biweight over a voxel pyramid (Open3D
   legacy pipeline; voxels not finer than the sample spacing) and scored in
   both directions with ``s`` = three times the residual the clouds' own
   roughness predicts at the right pose.  If the best fit leaves one
   rotation nearly free (Gelfand, Ikemoto, Rusinkiewicz & Levoy, "Geometrically
   stable sampling for the ICP algorithm", 3DIM 2003: a small eigenvalue of
   the point-to-plane information matrix, as for a surface of revolution),
   poses turned about that axis (and upside down) are searched as well.
3. **Verification.**  The best pose is accepted only if its overlap
   fraction, its point-to-plane RMS residual (against the residual expected
   from the clouds' roughness) and its normal agreement pass the preset's
   limits *and* it fits better than every distinct competitor by a margin,
   compared on the points both poses match (so that partial views, whose
   overlap depends on how their missing parts line up, are no evidence).
   A symmetric object offers two or more equally good poses: the pair is
   then reported unverified, with the competing pose, instead of guessed.
4. **Pose graph** (Choi, Zhou & Koltun, "Robust Reconstruction of Indoor
   Scenes", CVPR 2015; Open3D multiway registration): the passes are nodes,
   the verified pairs edges (a maximum spanning tree by score as odometry,
   the other verified pairs as loop closures); the optimised poses map every
   pass into the frame of pass 0, and the disagreement between each edge and
   the optimised poses is reported.

A manual fallback, :func:`register_from_picks`, turns three or more picked
point pairs into a rigid transform (Kabsch 1976 / Umeyama 1991 without
scale), refines it by the same ICP and takes the angle about a free axis
from the picks.

Units are millimetres.  A transform ``T`` (4 x 4) of a pair maps points of
its *source* cloud into the frame of its *target* cloud: ``x_t = T @ x_s``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from processing.errors import InputError

__all__ = [
    "MIN_POINTS",
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
]


class RegistrationError(InputError):
    """Input that cannot be registered; the message names the cloud or parameter and what to do."""


# ---------------------------------------------------------------------------
# Presets
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class RegistrationPreset:
    """Parameters of the registration (speed against accuracy).

    Voxel sizes are fractions of the pair's size ``D`` (the larger bounding-box
    diagonal of the two clouds), so one preset serves a 30 mm netsuke and a
    300 mm vase; correspondence distances are multiples of the voxel size.

    Attributes
    ----------
    name
        ``draft``, ``standard``, ``reference`` or a custom name.
    rotation_samples
        Number of starting rotations of the global search (super-Fibonacci).
    search_voxel
        Voxel size of the global search, as a fraction of ``D``.
    search_points
        At most this many source points in the first search stage.
    search_keep
        Fraction of the candidates kept after the first search stage.
    hypotheses
        Number of distinct hypotheses refined by the ICP pyramid.
    icp_voxels
        Voxel sizes of the ICP pyramid, coarse to fine, as fractions of ``D``.
        The second finest level is where competing hypotheses are compared.
    icp_iterations
        Largest number of ICP iterations per pyramid level.
    icp_points
        At most this many source points per ICP level (an even subsample).
    icp_distance
        Correspondence distance of the ICP and of the scores, in voxels.
    fpfh
        Also start from the FPFH + RANSAC estimate.
    min_overlap
        Smallest accepted overlap fraction (of the better covered cloud).
    max_rmse
        Largest accepted point-to-plane RMS residual, in units of the residual
        expected at the right pose: the residual of each cloud against itself
        (each point against a neighbour about a sample spacing away), which
        covers noise, relief between samples and normals.
    min_margin
        Smallest accepted relative margin by which the pose fits better than
        its strongest distinct competitor, on the points both match (below it
        the pose is ambiguous, e.g. a symmetric object).
    min_normal_agreement
        Smallest accepted mean cosine between matched normals.
    distinct_deg
        Hypotheses closer than this rotation (and ``distinct_fraction * D``
        displacement) count as the same pose.
    distinct_fraction
        See ``distinct_deg``.
    min_stability
        A motion whose information eigenvalue is below this fraction of the
        largest is "weak" (Gelfand et al. 2003): one weak rotation (a nearly
        symmetric shape) triggers a sweep about its axis, anything else makes
        the pair undetermined.
    score_scale
        Largest scale ``s`` of the truncated quadratic score, in voxels: a
        matched point adds ``max(0, 1 - (r / s)^2)`` for its point-to-plane
        residual ``r``.  Poses are scored with ``s`` = three times the residual
        expected at the right pose from the clouds' own roughness (capped by
        this), so that a pose is judged by how well the surfaces fit, not only
        by how much of them overlaps (partial views of a smooth shape overlap
        more when their missing parts are aligned).
    min_voxel_spacing
        No ICP voxel is finer than this many times the clouds' sample spacing
        (a voxel finer than the samples only leaves noisier normals).
    sweep_steps
        Starting angles of the sweep about a weak axis (full turn).

    Examples
    --------
    >>> PRESETS["draft"].rotation_samples < PRESETS["reference"].rotation_samples
    True
    """

    name: str
    rotation_samples: int
    search_voxel: float
    search_points: int
    search_keep: float
    hypotheses: int
    icp_voxels: tuple[float, ...]
    icp_iterations: int
    icp_points: int
    icp_distance: float
    fpfh: bool
    min_overlap: float = 0.25
    max_rmse: float = 6.0
    min_margin: float = 0.05
    min_normal_agreement: float = 0.8
    distinct_deg: float = 8.0
    distinct_fraction: float = 0.03
    min_stability: float = 0.01
    min_voxel_spacing: float = 1.0
    score_scale: float = 0.5
    sweep_steps: int = 72

    def __post_init__(self) -> None:
        if self.rotation_samples < 1:
            raise RegistrationError(f"preset {self.name!r}: rotation_samples must be >= 1")
        if not 0 < self.search_voxel < 1:
            raise RegistrationError(f"preset {self.name!r}: search_voxel must be in (0, 1)")
        if not self.icp_voxels or not all(0 < v < 1 for v in self.icp_voxels):
            raise RegistrationError(f"preset {self.name!r}: icp_voxels must be fractions in (0, 1)")
        if list(self.icp_voxels) != sorted(self.icp_voxels, reverse=True):
            raise RegistrationError(f"preset {self.name!r}: icp_voxels must go from coarse to fine")
        if self.hypotheses < 1 or self.search_points < 10 or not 0 < self.search_keep <= 1:
            raise RegistrationError(
                f"preset {self.name!r}: hypotheses >= 1, search_points >= 10 and "
                "search_keep in (0, 1] are required"
            )


#: The named presets.
PRESETS: dict[str, RegistrationPreset] = {
    "draft": RegistrationPreset(
        name="draft", rotation_samples=256, search_voxel=1 / 25, search_points=200,
        search_keep=0.125, hypotheses=4, icp_voxels=(1 / 50, 1 / 100, 1 / 200), icp_iterations=20,
        icp_points=5000, icp_distance=2.0, fpfh=False, sweep_steps=36,
    ),
    "standard": RegistrationPreset(
        name="standard", rotation_samples=1024, search_voxel=1 / 30, search_points=300,
        search_keep=0.0625, hypotheses=6, icp_voxels=(1 / 60, 1 / 150, 1 / 400),
        icp_iterations=30, icp_points=20000, icp_distance=2.0, fpfh=True,
    ),
    "reference": RegistrationPreset(
        name="reference", rotation_samples=4096, search_voxel=1 / 35, search_points=400,
        search_keep=0.03125, hypotheses=8, icp_voxels=(1 / 70, 1 / 150, 1 / 350, 1 / 800),
        icp_iterations=50, icp_points=60000, icp_distance=2.0, fpfh=True,
    ),
}


def registration_preset(preset: str | RegistrationPreset) -> RegistrationPreset:
    """The preset named ``preset`` (or ``preset`` itself if it already is one).

    Examples
    --------
    >>> registration_preset("standard").hypotheses
    6
    """
    if isinstance(preset, RegistrationPreset):
        return preset
    if preset not in PRESETS:
        raise RegistrationError(
            f"unknown registration preset {preset!r}; choose one of {', '.join(PRESETS)}"
        )
    return PRESETS[preset]


# ---------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PairResult:
    """Registration of one pair: ``transform`` maps ``source`` points into ``target``'s frame.

    Attributes
    ----------
    source, target
        Indices of the clouds (passes) of the pair.
    transform
        4 x 4 rigid transform, source frame -> target frame (mm).
    overlap
        Fraction of the better covered cloud with a partner in the other
        within the finest correspondence distance.
    overlap_source, overlap_target
        The same fraction for each cloud.
    rmse_mm
        Point-to-plane RMS residual of the matched points.
    expected_rmse_mm
        The residual expected at the right pose from the clouds' roughness
        (see ``RegistrationPreset.max_rmse``).
    normal_agreement
        Mean cosine between matched normals (absolute value when a cloud's
        normals were estimated, hence unoriented).
    score
        Truncated quadratic score of the pose (0..1, the mean of both
        directions) where the hypotheses were compared.
    margin
        Relative margin by which the pose fits better than its strongest
        distinct competitor on the points both match (1.0 when every
        hypothesis converged to this pose; negative if the competitor fits
        better; NaN for manual picks and a given initial pose).
    second_rotation_deg
        Rotation between this pose and that competitor (NaN if there is none).
    verified
        Whether every check passed.
    reason
        ``"ok"`` or why the pair is not verified.
    seconds
        Wall-clock time of the pair.
    method
        ``"global"``, ``"picks"`` or ``"initial"``.
    """

    source: int
    target: int
    transform: NDArray[np.float64]
    overlap: float
    overlap_source: float
    overlap_target: float
    rmse_mm: float
    expected_rmse_mm: float
    normal_agreement: float
    score: float
    margin: float
    second_rotation_deg: float
    verified: bool
    reason: str
    seconds: float
    method: str

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (the transform as nested lists)."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["transform"] = np.asarray(self.transform).tolist()
        for k, v in out.items():
            if isinstance(v, float) and not math.isfinite(v):
                out[k] = None
        return out


@dataclass(frozen=True)
class PassPose:
    """Final pose of one pass: ``transform`` maps the pass into the frame of pass 0.

    ``transform`` is ``None`` when the pass is not connected to pass 0 by
    verified pairs (``registered`` is then False and ``reason`` says why).
    """

    index: int
    transform: NDArray[np.float64] | None
    registered: bool
    reason: str


@dataclass(frozen=True)
class PoseGraphConsistency:
    """Disagreement between the pair transforms and the optimised poses.

    Attributes
    ----------
    max_rotation_deg
        Largest rotation between an edge's transform and the relative pose of
        its two optimised nodes.
    max_displacement_mm
        Largest displacement of an edge's source points between the two.
    edges
        Per edge ``(source, target, rotation_deg, displacement_mm, confidence)``;
        the confidence is the optimiser's line-process weight (near 0 for a
        loop closure it rejected).
    """

    max_rotation_deg: float
    max_displacement_mm: float
    edges: tuple[tuple[int, int, float, float, float], ...]


@dataclass(frozen=True)
class RegistrationResult:
    """Registration of several passes.

    Attributes
    ----------
    poses
        One :class:`PassPose` per pass (pass 0 is the identity).
    pairs
        Every pairwise result, verified or not.
    consistency
        Pose-graph consistency (None with fewer than two registered passes).
    preset
        The preset used.
    seconds
        Total wall-clock time.
    """

    poses: tuple[PassPose, ...]
    pairs: tuple[PairResult, ...]
    consistency: PoseGraphConsistency | None
    preset: RegistrationPreset
    seconds: float

    @property
    def all_registered(self) -> bool:
        """True if every pass has a pose."""
        return all(p.registered for p in self.poses)


# ---------------------------------------------------------------------------
# Small geometry helpers
# ---------------------------------------------------------------------------


def rotation_samples(n: int) -> NDArray[np.float64]:
    """``n`` rotation matrices spread evenly over SO(3) (super-Fibonacci spiral).

    Alexa (CVPR 2022), algorithm 1: sample ``i`` is the unit quaternion
    ``(r sin a, r cos a, R sin b, R cos b)`` with ``s = i + 1/2``,
    ``r = sqrt(s / n)``, ``R = sqrt(1 - s / n)``, ``a = 2 pi s / sqrt(2)``,
    ``b = 2 pi s / psi`` and ``psi^4 = psi + 4``.

    Parameters
    ----------
    n
        Number of rotations (>= 1).

    Returns
    -------
    ndarray
        ``(n, 3, 3)`` proper rotation matrices.

    Examples
    --------
    >>> r = rotation_samples(100)
    >>> r.shape, bool(np.allclose(r @ r.transpose(0, 2, 1), np.eye(3)))
    ((100, 3, 3), True)
    >>> bool(np.allclose(np.linalg.det(r), 1.0))
    True
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise RegistrationError(f"rotation_samples: n must be a positive integer, got {n!r}")
    psi = 1.533751168755204288118041
    s = np.arange(n) + 0.5
    r = np.sqrt(s / n)
    big = np.sqrt(1.0 - s / n)
    a = 2.0 * np.pi * s / np.sqrt(2.0)
    b = 2.0 * np.pi * s / psi
    q = np.stack([r * np.sin(a), r * np.cos(a), big * np.sin(b), big * np.cos(b)], axis=1)
    return _quat_to_matrix(q)


def _quat_to_matrix(q: NDArray[np.float64]) -> NDArray[np.float64]:
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def _rodrigues(w: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices ``(K, 3, 3)`` of rotation vectors ``(K, 3)``."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    k = w / np.where(small, 1.0, theta)[:, None]
    kx = np.zeros((len(w), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx = kx - kx.transpose(0, 2, 1)
    s = np.sin(theta)[:, None, None]
    c = (1.0 - np.cos(theta))[:, None, None]
    return np.eye(3) + s * kx + c * (kx @ kx)


def _rotation_angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angle (deg) of ``a^T b`` for stacks of rotations (broadcasting):
    ``atan2(sin, cos)`` from its skew part and trace, accurate near 0 and 180 degrees.
    """
    m = np.einsum("...ji,...jk->...ik", a, b)
    cos = (np.trace(m, axis1=-2, axis2=-1) - 1.0) / 2.0
    skew = np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1)
    return np.degrees(np.arctan2(np.linalg.norm(skew, axis=-1) / 2.0, cos))


def transform_points(transform: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Apply a 4 x 4 rigid transform to ``(N, 3)`` points.

    Examples
    --------
    >>> t = np.eye(4); t[:3, 3] = [1, 2, 3]
    >>> transform_points(t, [[0, 0, 0]]).tolist()
    [[1.0, 2.0, 3.0]]
    """
    t = np.asarray(transform, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return p @ t[:3, :3].T + t[:3, 3]


def pose_difference(
    a: ArrayLike, b: ArrayLike, points: ArrayLike | None = None
) -> tuple[float, float]:
    """Rotation (degrees) and displacement (mm) between two rigid transforms.

    Parameters
    ----------
    a, b
        4 x 4 rigid transforms.
    points
        Optional ``(N, 3)`` points (mm): the displacement is then the largest
        ``|a x - b x|`` over them, which does not depend on where the origin
        is; without points it is the difference of the translations.

    Returns
    -------
    tuple of float
        ``(rotation_deg, displacement_mm)``.

    Examples
    --------
    >>> a = np.eye(4); b = np.eye(4); b[:3, 3] = [0, 0.1, 0]
    >>> [round(v, 6) for v in pose_difference(a, b)]
    [0.0, 0.1]
    """
    ta = np.asarray(a, dtype=np.float64)
    tb = np.asarray(b, dtype=np.float64)
    rot = float(_rotation_angle_deg(ta[:3, :3], tb[:3, :3]))
    if points is None:
        return rot, float(np.linalg.norm(ta[:3, 3] - tb[:3, 3]))
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    disp = np.linalg.norm(transform_points(ta, p) - transform_points(tb, p), axis=1)
    return rot, float(disp.max()) if len(disp) else 0.0


def rigid_from_picks(
    source_points: ArrayLike, target_points: ArrayLike
) -> tuple[NDArray[np.float64], float]:
    """Rigid transform (no scale) that best maps picked source points onto target points.

    Kabsch (1976) / Umeyama (1991) without scale: the rotation from the SVD of
    the cross-covariance of the centred pairs, with the reflection removed.

    Parameters
    ----------
    source_points, target_points
        ``(M, 3)`` corresponding points (mm), ``M >= 3``, not collinear.

    Returns
    -------
    tuple
        ``(transform, rms_mm)``: the 4 x 4 transform source -> target and the
        RMS distance of the mapped picks to their partners.

    Examples
    --------
    >>> src = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], float)
    >>> t, rms = rigid_from_picks(src, src + [1, 2, 3])
    >>> np.round(t[:3, 3], 9).tolist(), rms < 1e-9
    ([1.0, 2.0, 3.0], True)
    """
    src = _picks_array(source_points, "source_points")
    tgt = _picks_array(target_points, "target_points")
    if src.shape != tgt.shape:
        raise RegistrationError(
            f"source_points and target_points must pair up one to one, got {len(src)} and "
            f"{len(tgt)} points"
        )
    for name, p in (("source_points", src), ("target_points", tgt)):
        centred = p - p.mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[0] == 0.0 or sv[1] <= 1e-6 * sv[0]:
            raise RegistrationError(
                f"{name} are collinear (or coincide): pick at least 3 points that span a "
                "triangle, well apart from each other"
            )
    cs, ct = src.mean(axis=0), tgt.mean(axis=0)
    h = (src - cs).T @ (tgt - ct)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = ct - r @ cs
    rms = float(np.sqrt(np.mean(np.sum((transform_points(t, src) - tgt) ** 2, axis=1))))
    return t, rms


def _picks_array(points: ArrayLike, name: str) -> NDArray[np.float64]:
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RegistrationError(f"{name} must be an (M, 3) array of points in mm: {exc}") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise RegistrationError(f"{name} must be an (M, 3) array of points in mm, got shape {p.shape}")
    if len(p) < 3:
        raise RegistrationError(f"{name}: at least 3 picked point pairs are needed, got {len(p)}")
    if not np.all(np.isfinite(p)):
        raise RegistrationError(f"{name} contains NaN or infinite coordinates; pick the points again")
    return p


# ---------------------------------------------------------------------------
# Clouds
# ---------------------------------------------------------------------------

#: Fewest points a cloud must have to be registered.
MIN_POINTS = 10


@dataclass
class _Level:
    """A cloud downsampled on one voxel grid, with lazily built search structures."""

    points: NDArray[np.float64]
    normals: NDArray[np.float64]
    _pcd: Any = None
    _tree: cKDTree | None = None
    _roughness: dict[float, float] = field(default_factory=dict)
    _grids: dict[tuple[float, float], Any] = field(default_factory=dict)

    @property
    def pcd(self) -> Any:
        if self._pcd is None:
            import open3d as o3d

            self._pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points))
            self._pcd.normals = o3d.utility.Vector3dVector(self.normals)
        return self._pcd

    def source_pcd(self, max_points: int) -> Any:
        """The level as an ICP source: at most ``max_points`` points (an even stride)."""
        if len(self.points) <= max_points:
            return self.pcd
        every = math.ceil(len(self.points) / max_points)
        return self.pcd.uniform_down_sample(every)

    def grid(self, cell: float, reach: float) -> _NearestGrid:
        """Nearest-neighbour lookup grid of the level (cached), see :class:`_NearestGrid`."""
        key = (float(cell), float(reach))
        if key not in self._grids:
            self._grids[key] = _NearestGrid(self.points, cell, reach)
        return self._grids[key]

    @property
    def padded(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Points and normals with a sentinel point far away appended (index ``len(points)``)."""
        far = np.abs(self.points).max() * 1e3 + 1e6
        return (np.concatenate([self.points, [[far, far, far]]]),
                np.concatenate([self.normals, [[0.0, 0.0, 0.0]]]))

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.points)
        return self._tree

    def roughness(self, spacing: float) -> float:
        """Robust RMS point-to-plane residual of each point against a neighbour in the
        same cloud at least ``spacing / 2`` away (mm): what a perfect registration
        leaves of two samplings of this surface with sample spacing ``spacing``
        (noise, relief between samples, normals).  The distance floor keeps a
        profile's own next point (much closer than the profiles are apart in
        scan data) from making the estimate too small.
        """
        key = round(float(spacing), 9)
        if key not in self._roughness:
            k = min(9, len(self.points))
            dist, idx = self.tree.query(self.points, k=k, workers=-1)
            far = dist[:, 1:] >= 0.5 * spacing
            first = np.where(far.any(axis=1), np.argmax(far, axis=1), k - 2) + 1
            j = idx[np.arange(len(idx)), first]
            r = np.einsum("ij,ij->i", self.points - self.points[j], self.normals[j])
            self._roughness[key] = float(np.sqrt(np.median(r * r) / 0.4549))  # median of chi2(1)
        return self._roughness[key]


@dataclass
class _Cloud:
    """A validated cloud with its pyramid of downsampled levels (cached per voxel size)."""

    points: NDArray[np.float64]
    normals: NDArray[np.float64] | None
    name: str
    levels: dict[tuple[float, bool], _Level] = field(default_factory=dict)
    _spacing: float | None = None

    @property
    def oriented(self) -> bool:
        return self.normals is not None

    @property
    def diagonal(self) -> float:
        return float(np.linalg.norm(self.points.max(axis=0) - self.points.min(axis=0)))

    @property
    def spacing(self) -> float:
        """Mean distance between samples on the surface (mm): ``1 / sqrt(density)``,
        from the distance ``d_8`` to the 8th nearest neighbour (``pi d_8^2`` holds
        8 samples), which spans neighbouring profiles of unevenly sampled scans.
        """
        if self._spacing is None:
            every = max(1, len(self.points) // 2000)
            k = min(9, len(self.points))
            d, _ = cKDTree(self.points).query(self.points[::every], k=k, workers=-1)
            self._spacing = float(np.median(d[:, -1]) * math.sqrt(math.pi / max(k - 1, 1)))
        return self._spacing

    def level(self, voxel: float, fallback: bool = True) -> _Level:
        """The cloud downsampled on a ``voxel`` grid (mm), with unit normals; where the
        neighbourhood is too thin for a normal, the normal of a level twice as coarse
        is used (``fallback``).
        """
        key = (float(voxel), fallback)
        if key not in self.levels:
            coarser = None
            if fallback and 2.0 * voxel < 0.25 * self.diagonal:
                coarser = lambda: self.level(2.0 * voxel, fallback=False)
            self.levels[key] = _Level(*_downsample(self.points, self.normals, float(voxel), coarser))
        return self.levels[key]


def _downsample(
    points: NDArray[np.float64],
    normals: NDArray[np.float64] | None,
    voxel: float,
    coarser: Any = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Voxel-grid average of the points, with normals fitted to the neighbourhood (PCA).

    Fitted normals describe the sampled surface at this scale better than
    averaged input normals; the input normals, when given, only orient them
    (otherwise they point away from the centroid).  Scan data is sampled
    unevenly (dense along a profile, sparser across profiles): where the
    neighbours within ``3 voxel`` are nearly collinear (the middle eigenvalue
    of their covariance below 5 % of the largest), the normal of the nearest
    point of the ``coarser`` level (a callable returning it) is used instead.
    """
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(normals)
    down = pcd.voxel_down_sample(voxel)
    p = np.asarray(down.points).copy()
    guide = np.asarray(down.normals).copy() if normals is not None else p - p.mean(axis=0)
    down.estimate_covariances(o3d.geometry.KDTreeSearchParamHybrid(radius=3.0 * voxel, max_nn=20))
    evals, evecs = np.linalg.eigh(np.asarray(down.covariances))
    n = evecs[:, :, 0].copy()
    bad = evals[:, 1] < 0.05 * np.maximum(evals[:, 2], 1e-300)
    if bad.any() and coarser is not None:
        lvl = coarser()
        _, idx = lvl.tree.query(p[bad], workers=-1)
        n[bad] = lvl.normals[idx]
    flip = np.sum(n * guide, axis=1) < 0
    n[flip] *= -1.0
    return p, n


def _as_cloud(points: ArrayLike, normals: ArrayLike | None, name: str) -> _Cloud:
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RegistrationError(f"{name}: points must be an (N, 3) array in mm: {exc}") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise RegistrationError(f"{name}: points must be an (N, 3) array in mm, got shape {p.shape}")
    if len(p) == 0:
        raise RegistrationError(f"{name} is empty: it has no points to register")
    bad = ~np.all(np.isfinite(p), axis=1)
    if bad.any():
        raise RegistrationError(
            f"{name} has {int(bad.sum())} NaN or infinite points of {len(p)}; drop them first "
            "(e.g. points[np.isfinite(points).all(axis=1)])"
        )
    if len(p) < MIN_POINTS:
        raise RegistrationError(
            f"{name} has only {len(p)} point(s); registration needs at least {MIN_POINTS}"
        )
    centred = p - p.mean(axis=0)
    sv = np.linalg.svd(centred[:: max(1, len(p) // 20000)], compute_uv=False)
    if sv[0] == 0.0:
        raise RegistrationError(f"{name}: all {len(p)} points coincide; there is no shape to register")
    if sv[1] <= 1e-6 * sv[0]:
        raise RegistrationError(
            f"{name}: all points lie on a line; a line's rotation about itself cannot be registered"
        )
    if sv[2] <= 1e-6 * sv[0]:
        raise RegistrationError(
            f"{name}: all points lie in one plane; a plane slides and turns within itself, so "
            "it cannot be registered (scan some relief or use picked points)"
        )
    n_arr = None
    if normals is not None:
        n_arr = np.asarray(normals, dtype=np.float64)
        if n_arr.shape != p.shape:
            raise RegistrationError(
                f"{name}: normals must have the shape of the points {p.shape}, got {n_arr.shape}"
            )
        if not np.all(np.isfinite(n_arr)):
            raise RegistrationError(f"{name}: normals contain NaN or infinite values")
    return _Cloud(points=p, normals=n_arr, name=name)


# ---------------------------------------------------------------------------
# Global search
# ---------------------------------------------------------------------------


class _NearestGrid:
    """Nearest target point of every cell of a regular grid: O(1) approximate nearest neighbours.

    Cells farther than ``reach`` from every point hold the index ``len(points)``:
    callers append a sentinel point far away (see :attr:`_Level.padded`).
    """

    def __init__(self, points: NDArray[np.float64], cell: float, reach: float, max_cells: int = 300_000):
        lo = points.min(axis=0) - reach
        hi = points.max(axis=0) + reach
        ext = hi - lo
        cell = max(cell, float(np.prod(ext) / max_cells) ** (1.0 / 3.0))
        shape = np.maximum(np.ceil(ext / cell).astype(int), 1)
        axes = [lo[k] + (np.arange(shape[k]) + 0.5) * cell for k in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        # cells farther than ``reach`` from the cloud point at a sentinel far away (no match)
        _, idx = cKDTree(points).query(centres, distance_upper_bound=reach + cell, workers=-1)
        self.lo, self.cell, self.shape = lo, cell, shape
        self.index = idx.astype(np.int32)  # len(points) where nothing is within reach

    def __call__(self, x: NDArray[np.float64]) -> NDArray[np.int32]:
        ijk = np.floor((x - self.lo) / self.cell).astype(np.int64)
        np.clip(ijk, 0, self.shape - 1, out=ijk)
        flat = (ijk[..., 0] * self.shape[1] + ijk[..., 1]) * self.shape[2] + ijk[..., 2]
        return self.index[flat]


def _batch_icp(
    rot: NDArray[np.float64],
    trans: NDArray[np.float64],
    src: NDArray[np.float64],
    tgt: NDArray[np.float64],
    tgt_n: NDArray[np.float64],
    grid: _NearestGrid,
    taus: Sequence[float],
    score_tau: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Point-to-plane ICP of ``K`` candidate poses at once; returns the poses and their scores.

    Each iteration linearises ``R <- exp([w]) R``, ``t <- exp([w]) t + v`` and
    solves the damped 6 x 6 normal equations of the residuals
    ``(x - q) . n_q`` of the correspondences closer than ``tau``.
    """
    rot = rot.copy()
    trans = trans.copy()
    eye6 = np.eye(6)
    src_t = src.T
    for tau in taus:
        x = np.matmul(rot, src_t).transpose(0, 2, 1) + trans[:, None, :]
        idx = grid(x)
        nq = tgt_n[idx]
        diff = x - tgt[idx]
        w = (np.sum(diff * diff, axis=2) < tau * tau).astype(np.float64)
        r = np.sum(diff * nq, axis=2)
        jac = np.concatenate([np.cross(x, nq), nq], axis=2)
        jw = jac * w[..., None]
        a = np.matmul(jw.transpose(0, 2, 1), jac)
        b = -np.matmul(jw.transpose(0, 2, 1), r[..., None])
        damp = 1e-3 * np.trace(a, axis1=1, axis2=2)[:, None, None] / 6.0 + 1e-9
        step = np.linalg.solve(a + damp * eye6, b)[..., 0]
        omega = step[:, :3]
        ang = np.linalg.norm(omega, axis=1, keepdims=True)
        omega = omega * np.minimum(1.0, 0.5 / np.maximum(ang, 1e-12))
        dr = _rodrigues(omega)
        rot = dr @ rot
        trans = np.matmul(dr, trans[..., None])[..., 0] + step[:, 3:]
    score, _, _ = _batch_score(rot, trans, src, tgt, tgt_n, grid, taus[-1], score_tau)
    return rot, trans, score


def _batch_score(
    rot: NDArray[np.float64],
    trans: NDArray[np.float64],
    src: NDArray[np.float64],
    tgt: NDArray[np.float64],
    tgt_n: NDArray[np.float64],
    grid: _NearestGrid,
    tau: float,
    score_tau: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Truncated quadratic score of ``K`` poses (source -> target, approximate nearest
    neighbours), with the per-point contributions ``(K, N)`` and matches ``(K, N)``.
    """
    x = np.matmul(rot, src.T).transpose(0, 2, 1) + trans[:, None, :]
    idx = grid(x)
    diff = x - tgt[idx]
    hit = np.sum(diff * diff, axis=2) < tau * tau
    r = np.sum(diff * tgt_n[idx], axis=2)
    part = np.where(hit, np.maximum(0.0, 1.0 - (r / score_tau) ** 2), 0.0)
    return part.mean(axis=1), part, hit


def _centroid_shift(rot: NDArray[np.float64], c_s: NDArray[np.float64], c_t: NDArray[np.float64]) -> NDArray[np.float64]:
    return c_t - np.einsum("kij,j->ki", rot, c_s)


def _fpfh_candidate(src: _Level, tgt: _Level, voxel: float, seed: int) -> NDArray[np.float64] | None:
    """FPFH + RANSAC estimate (Rusu et al. 2009), or None if it finds nothing."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel, max_nn=100)
    fs = reg.compute_fpfh_feature(src.pcd, param)
    ft = reg.compute_fpfh_feature(tgt.pcd, param)
    o3d.utility.random.seed(seed)
    res = reg.registration_ransac_based_on_feature_matching(
        src.pcd, tgt.pcd, fs, ft, True, 1.5 * voxel,
        reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
         reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        reg.RANSACConvergenceCriteria(20000, 0.999),
    )
    if res.fitness <= 0.0:
        return None
    return np.asarray(res.transformation, dtype=np.float64)


def _global_search(
    src: _Cloud, tgt: _Cloud, scale: float, preset: RegistrationPreset, rng: np.random.Generator
) -> list[NDArray[np.float64]]:
    """Distinct coarse hypotheses (4 x 4, best first) from the sampled rotations."""
    voxel = preset.search_voxel * scale
    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    grid = t_lvl.grid(voxel / 2.0, 6.0 * voxel)
    c_s, c_t = s_lvl.points.mean(axis=0), t_lvl.points.mean(axis=0)

    rot = np.concatenate([np.eye(3)[None], rotation_samples(preset.rotation_samples)])
    trans = _centroid_shift(rot, c_s, c_t)
    sub = _subsample(s_lvl.points, preset.search_points, rng)
    # stage A: every start, few points, shrinking correspondence distance
    taus_a = voxel * np.array([6.0, 4.0, 3.0, 2.5, 2.0, 2.0])
    rot, trans, score = _chunked_icp(rot, trans, sub, t_lvl, grid, taus_a, taus_a[-1])
    keep = max(4 * preset.hypotheses, math.ceil(preset.search_keep * len(rot)))
    order = np.argsort(-score)[:keep]
    rot, trans = rot[order], trans[order]
    if preset.fpfh:
        t_f = _fpfh_candidate(s_lvl, t_lvl, voxel, int(rng.integers(1 << 30)))
        if t_f is not None:
            rot = np.concatenate([rot, t_f[None, :3, :3]])
            trans = np.concatenate([trans, t_f[None, :3, 3]])
    # stage B: the survivors, more points, tight distance
    full = _subsample(s_lvl.points, 4 * preset.search_points, rng)
    taus_b = voxel * np.array([2.0, 2.0, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5])
    rot, trans, score = _chunked_icp(rot, trans, full, t_lvl, grid, taus_b, taus_b[-1])
    order = np.argsort(-score)
    poses = np.zeros((len(order), 4, 4))
    poses[:, :3, :3] = rot[order]
    poses[:, :3, 3] = trans[order]
    poses[:, 3, 3] = 1.0
    return _distinct(poses, c_s, preset, scale)[: preset.hypotheses]


def _chunked_icp(
    rot: NDArray[np.float64],
    trans: NDArray[np.float64],
    src: NDArray[np.float64],
    tgt: _Level,
    grid: _NearestGrid,
    taus: NDArray[np.float64],
    score_tau: float,
    budget: int = 400_000,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:func:`_batch_icp` in chunks of candidates that keep the arrays a few tens of MB."""
    step = max(1, budget // max(1, len(src)))
    pts, nrm = tgt.padded
    parts = [
        _batch_icp(rot[k : k + step], trans[k : k + step], src, pts, nrm, grid, taus, score_tau)
        for k in range(0, len(rot), step)
    ]
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))  # type: ignore[return-value]


def _distinct(
    poses: NDArray[np.float64], c_s: NDArray[np.float64], preset: RegistrationPreset, scale: float
) -> list[NDArray[np.float64]]:
    """Greedy non-maximum suppression of poses (already sorted best first)."""
    kept: list[NDArray[np.float64]] = []
    centres = np.einsum("kij,j->ki", poses[:, :3, :3], c_s) + poses[:, :3, 3]
    alive = np.ones(len(poses), dtype=bool)
    for k in range(len(poses)):  # loop over hypotheses (a few dozen), not points
        if not alive[k]:
            continue
        kept.append(poses[k])
        if len(kept) >= 4 * preset.hypotheses:
            break
        same = (_rotation_angle_deg(poses[k, :3, :3][None], poses[:, :3, :3]) < preset.distinct_deg) & (
            np.linalg.norm(centres - centres[k], axis=1) < preset.distinct_fraction * scale
        )
        alive &= ~same
    return kept


# ---------------------------------------------------------------------------
# Refinement and verification
# ---------------------------------------------------------------------------


def _pyramid(preset: RegistrationPreset, scale: float, *clouds: _Cloud) -> tuple[float, ...]:
    """The ICP voxel sizes (mm) of a pair: the preset's fractions of ``scale``, but not
    finer than the clouds' sample spacing (finer voxels only add noisy normals).
    """
    floor = preset.min_voxel_spacing * max(c.spacing for c in clouds)
    out: list[float] = []
    for frac in preset.icp_voxels:
        v = max(frac * scale, floor)
        if not out or v < out[-1] * 0.999:
            out.append(v)
    return tuple(out)


def _icp_pyramid(
    src: _Cloud, tgt: _Cloud, preset: RegistrationPreset, init: NDArray[np.float64],
    levels: Sequence[float], first_distance: float | None = None, settled: bool = False,
) -> NDArray[np.float64]:
    """Point-to-plane ICP (Open3D legacy pipeline) down a pyramid of voxel sizes (mm).

    Residuals are weighted by Tukey's biweight with ``k`` = half a voxel
    (a whole voxel on the first level unless the pose has ``settled`` at a
    coarser level already): normals fitted across sharp edges and points
    beyond the other cloud's border would otherwise pull the pose by tenths of
    a degree.
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    t = np.asarray(init, dtype=np.float64)
    for k, voxel in enumerate(levels):
        dist = preset.icp_distance * voxel
        if k == 0 and first_distance is not None:
            dist = max(dist, first_distance)
        kernel = reg.TukeyLoss(k=(0.5 * dist) if (k == 0 and not settled) else 0.5 * voxel)
        res = reg.registration_icp(
            src.level(voxel).source_pcd(preset.icp_points), tgt.level(voxel).pcd, dist, t,
            reg.TransformationEstimationPointToPlane(kernel),
            reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7,
                                       max_iteration=preset.icp_iterations),
        )
        t = np.asarray(res.transformation, dtype=np.float64)
    return t


@dataclass(frozen=True)
class _Score:
    """Fit of a pose in both directions; ``score`` is filled in by :meth:`at`.

    ``residuals`` holds the point-to-plane residual of every point of the
    source and of the target level (NaN where there is no partner within the
    correspondence distance).
    """

    overlap_source: float
    overlap_target: float
    rmse_mm: float
    normal_agreement: float
    score: float = math.nan
    tau_s: float = math.nan
    expected_mm: float = math.nan
    residuals: tuple[NDArray[np.float64], NDArray[np.float64]] = (np.zeros(0), np.zeros(0))

    def at(self, tau_s: float) -> _Score:
        """This fit with its truncated quadratic score at scale ``tau_s`` (mean of both directions)."""
        score = 0.5 * sum(float(np.mean(_contribution(r, tau_s))) if len(r) else 0.0 for r in self.residuals)
        return replace(self, score=score, tau_s=tau_s)


def _contribution(r: NDArray[np.float64], tau_s: float) -> NDArray[np.float64]:
    """Truncated quadratic ``max(0, 1 - (r / tau_s)^2)``, 0 where ``r`` is NaN (no partner)."""
    with np.errstate(invalid="ignore"):
        return np.where(np.isnan(r), 0.0, np.maximum(0.0, 1.0 - (np.nan_to_num(r) / tau_s) ** 2))


def _common_quality(
    ra: NDArray[np.float64], rb: NDArray[np.float64], tau_s: float
) -> tuple[float, float, int]:
    """Mean contribution of two poses over the points matched under both (the jointly
    overlapping part, where partial views cannot favour either), and its size.
    """
    both = ~np.isnan(ra) & ~np.isnan(rb)
    n = int(both.sum())
    if n == 0:
        return 0.0, 0.0, 0
    return float(_contribution(ra[both], tau_s).mean()), float(_contribution(rb[both], tau_s).mean()), n


def _one_way(
    a: _Level, b: _Level, t: NDArray[np.float64], tau: float, signed: bool
) -> tuple[float, NDArray[np.float64], float]:
    x = transform_points(t, a.points)
    nx = a.normals @ t[:3, :3].T
    d, idx = b.tree.query(x, distance_upper_bound=tau, workers=-1)
    hit = np.isfinite(d)
    r = np.full(len(x), np.nan)
    if not hit.any():
        return 0.0, r, 0.0
    i = idx[hit]
    r[hit] = np.einsum("ij,ij->i", x[hit] - b.points[i], b.normals[i])
    cos = np.einsum("ij,ij->i", nx[hit], b.normals[i])
    if not signed:
        cos = np.abs(cos)
    return float(hit.mean()), r, float(np.sum(cos))


def _evaluate(src: _Cloud, tgt: _Cloud, t: NDArray[np.float64], voxel: float, preset: RegistrationPreset) -> _Score:
    """Overlap, point-to-plane residuals and normal agreement of a pose, both directions."""
    tau = preset.icp_distance * voxel
    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    signed = src.oriented and tgt.oriented
    fs, rs, cs = _one_way(s_lvl, t_lvl, t, tau, signed)
    ft, rt, ct = _one_way(t_lvl, s_lvl, np.linalg.inv(t), tau, signed)
    r = np.concatenate([rs, rt])
    r = r[~np.isnan(r)]
    n = len(r)
    return _Score(
        overlap_source=fs,
        overlap_target=ft,
        rmse_mm=math.sqrt(float(r @ r) / n) if n else math.inf,
        normal_agreement=(cs + ct) / n if n else 0.0,
        expected_mm=_expected_residual(src, tgt, voxel),
        residuals=(rs, rt),
    )


def _expected_residual(src: _Cloud, tgt: _Cloud, voxel: float) -> float:
    """Point-to-plane RMS residual expected at the right pose at this level (mm)."""
    spacing = max(voxel, src.spacing, tgt.spacing)
    a, b = src.level(voxel).roughness(spacing), tgt.level(voxel).roughness(spacing)
    return math.sqrt(0.5 * (a * a + b * b))


def _score_scale(src: _Cloud, tgt: _Cloud, voxel: float, preset: RegistrationPreset) -> float:
    """Scale of the truncated quadratic score: three times the residual expected at the
    right pose from the clouds' roughness, kept within [0.02, score_scale] voxels.
    """
    expected = _expected_residual(src, tgt, voxel)
    return float(np.clip(3.0 * expected, 0.02 * voxel, preset.score_scale * voxel))


def _scored(fits: Sequence[_Score], tau_s: float) -> list[_Score]:
    """The fits scored on one scale ``tau_s`` (mm), see :func:`_score_scale`."""
    return [f.at(tau_s) for f in fits]


def _verdict(sc: _Score, margin: float, second_deg: float, voxel: float, preset: RegistrationPreset) -> tuple[bool, str]:
    reasons = []
    overlap = max(sc.overlap_source, sc.overlap_target)
    if not overlap >= preset.min_overlap:
        reasons.append(
            f"overlap {overlap:.1%} is below {preset.min_overlap:.0%} (the clouds share too little "
            "surface, or the pose is wrong)"
        )
    max_rmse = preset.max_rmse * max(sc.expected_mm, 0.01 * voxel)
    if not sc.rmse_mm <= max_rmse:
        reasons.append(
            f"RMS residual {sc.rmse_mm:.3g} mm exceeds {max_rmse:.3g} mm ({preset.max_rmse:g} x "
            "the clouds' own roughness)"
        )
    if sc.normal_agreement < preset.min_normal_agreement:
        reasons.append(
            f"matched normals disagree (mean cosine {sc.normal_agreement:.2f} < "
            f"{preset.min_normal_agreement:.2f})"
        )
    if math.isfinite(margin) and margin < preset.min_margin:
        reasons.append(
            f"ambiguous: a second pose {second_deg:.1f} deg away fits "
            f"{'nearly as well' if margin >= 0 else 'better'} where both overlap (margin {margin:.1%} < "
            f"{preset.min_margin:.0%}; a nearly symmetric shape?); pick points to register this pair"
        )
    return (not reasons), "; ".join(reasons) if reasons else "ok"


def _pair_scale(*clouds: _Cloud) -> float:
    return max(c.diagonal for c in clouds)


def _register(
    src: _Cloud,
    tgt: _Cloud,
    scale: float,
    preset: RegistrationPreset,
    rng: np.random.Generator,
    indices: tuple[int, int],
) -> PairResult:
    start = time.perf_counter()
    hyps = _global_search(src, tgt, scale, preset, rng)
    # every hypothesis down the pyramid but its finest level; decide there
    levels = _pyramid(preset, scale, src, tgt)
    upper = levels[:-1] if len(levels) > 1 else levels
    decide = upper[-1]
    refined = _refine_distinct(src, tgt, preset, hyps, upper)
    tau_s = _score_scale(src, tgt, decide, preset)
    scores = _scored([_evaluate(src, tgt, t, decide, preset) for t in refined], tau_s)
    best = int(np.argmax([sc.score for sc in scores]))
    # a nearly symmetric shape: sweep the poses about its weak axis
    weak_reason = ""
    sweep = _weak_axis(src.level(decide), tgt.level(decide), refined[best], decide, preset)
    if isinstance(sweep, str):
        weak_reason = sweep
    elif sweep is not None:
        axis, point = sweep
        swept = _axis_sweep(src, tgt, refined[best], axis, point, decide, preset, rng, tau_s)
        for t in _refine_distinct(src, tgt, preset, swept, upper[-1:]):
            refined.append(t)
            scores.append(_evaluate(src, tgt, t, decide, preset))
        scores = _scored(scores, tau_s)
        best = int(np.argmax([sc.score for sc in scores]))
    margin, second_deg = _margin(refined, scores, best, src.level(decide).points.mean(axis=0), scale, preset)
    if sweep is not None and not isinstance(sweep, str):
        again = _weak_axis(src.level(decide), tgt.level(decide), refined[best], decide, preset)
        if again is not None and not isinstance(again, str):
            m2, d2 = _sweep_margin(src, tgt, refined[best], again[0], again[1], decide, preset, rng, tau_s)
            if m2 < margin:
                margin, second_deg = m2, d2
    t = refined[best]
    if len(levels) > 1:
        t = _icp_pyramid(src, tgt, preset, t, levels[-1:], settled=True)
    fine = levels[-1]
    sc = replace(_evaluate(src, tgt, t, fine, preset), score=scores[best].score)
    ok, reason = _verdict(sc, margin, second_deg, fine, preset)
    if weak_reason:
        reason = weak_reason if ok else f"{reason}; {weak_reason}"
        ok = False
    return _pair_result(indices, t, sc, margin, second_deg, ok, reason, start, "global")


def _refine_distinct(
    src: _Cloud, tgt: _Cloud, preset: RegistrationPreset,
    hyps: Sequence[NDArray[np.float64]], levels: Sequence[float],
) -> list[NDArray[np.float64]]:
    """ICP of each hypothesis level by level (voxel sizes in mm), merging hypotheses
    that meet in one basin.
    """
    poses = list(hyps)
    centre = src.level(levels[0]).points.mean(axis=0)[None]
    for k, voxel in enumerate(levels):
        out: list[NDArray[np.float64]] = []
        for h in poses:
            t = _icp_pyramid(src, tgt, preset, h, [voxel], settled=k > 0)
            differences = (pose_difference(t, o, centre) for o in out)
            if all(rot > 1.0 or disp > voxel for rot, disp in differences):
                out.append(t)
        poses = out
    return poses


def _competitor_margin(
    overlap: float, others: Sequence[tuple[float, float, float, int, float]], matched: int
) -> tuple[float, float]:
    """Relative margin of a pose over its strongest competitor.

    ``others`` holds, per pose distinct from it, ``(overlap, own, theirs, n,
    rotation_deg)``: its overlap fraction, the mean truncated quadratic
    contribution of this pose (``own``) and of the competitor (``theirs``) over
    the ``n`` points both match, and the rotation between the two.  A
    competitor explains at least half as much of the clouds and shares at
    least a quarter of this pose's ``matched`` points; the margin is the
    smallest ``(own - theirs) / own``.  The comparison is on the common
    points, not on the overlap: partial views of a symmetric shape overlap more
    or less depending on how their missing parts line up, which is no evidence.
    Returns ``(1.0, nan)`` without competitors.
    """
    margin, deg = 1.0, math.nan
    for ov, own, theirs, n, rot in others:
        if ov >= 0.5 * overlap and n >= 0.25 * matched:
            m = (own - theirs) / own if own > 0 else 0.0
            if m < margin:
                margin, deg = m, rot
    return margin, deg


def _margin(
    poses: Sequence[NDArray[np.float64]], scores: Sequence[_Score], best: int,
    centre: NDArray[np.float64], scale: float, preset: RegistrationPreset,
) -> tuple[float, float]:
    """Margin of ``poses[best]`` over its distinct competitors, and the rotation to the
    strongest one (see :func:`_competitor_margin`; both directions pooled).
    """
    b = scores[best]
    rb = np.concatenate(b.residuals)
    others = []
    for t, sc in zip(poses, scores):
        rot, disp = pose_difference(poses[best], t, centre[None])
        if rot >= preset.distinct_deg or disp >= preset.distinct_fraction * scale:
            own, theirs, n = _common_quality(rb, np.concatenate(sc.residuals), b.tau_s)
            others.append((max(sc.overlap_source, sc.overlap_target), own, theirs, n, rot))
    matched = int(np.sum(~np.isnan(rb)))
    return _competitor_margin(max(b.overlap_source, b.overlap_target), others, matched)


def _weak_axis(
    src: _Level, tgt: _Level, t: NDArray[np.float64], voxel: float, preset: RegistrationPreset
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | str | None:
    """The axis (direction, point) of a single weak rotation at ``t``, a reason if the
    pose is undetermined in another way, or None if the fit is stable.
    """
    evals, evecs, c, length = _stability(src, tgt, t, preset.icp_distance * voxel)
    if evals[-1] <= 0:
        return "undetermined: no matched points to judge the fit"
    ratio = evals / evals[-1]
    weak = ratio < preset.min_stability
    if not weak.any():
        return None
    e = evecs[:, 0]
    rot_part = float(np.linalg.norm(e[:3]))
    if weak.sum() == 1 and rot_part > 0.7:
        omega = e[:3] / length
        v = e[3:]
        point = c + np.cross(omega, v) / float(omega @ omega)
        return omega / np.linalg.norm(omega), point
    return (
        f"undetermined: {int(weak.sum())} direction(s) of motion barely change the fit "
        f"(stability {ratio[0]:.1e} < {preset.min_stability:g}); the shape is nearly a sphere, "
        "cylinder or plane: pick points to register this pair"
    )


def _axis_turns(
    t: NDArray[np.float64], axis: NDArray[np.float64], point: NDArray[np.float64], steps: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``t`` turned about an axis (target frame) by ``steps`` even angles, and the same
    after a half turn about an axis across it (the shape upside down); returns the
    rotations, translations and the rotation angle of each from ``t`` (deg).
    """
    phi = 2.0 * np.pi * np.arange(steps) / steps
    turn = _rodrigues(phi[:, None] * axis[None, :])
    across = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    flip = _rodrigues(np.pi * across[None, :] / np.linalg.norm(across))[0]
    turn = np.concatenate([turn, turn @ flip])
    rot = turn @ t[:3, :3]
    trans = np.einsum("kij,j->ki", turn, t[:3, 3] - point) + point
    return rot, trans, _rotation_angle_deg(turn, np.eye(3))


def _axis_sweep(
    src: _Cloud, tgt: _Cloud, t: NDArray[np.float64], axis: NDArray[np.float64], point: NDArray[np.float64],
    voxel: float, preset: RegistrationPreset, rng: np.random.Generator, score_tau: float,
) -> list[NDArray[np.float64]]:
    """Distinct poses found by turning ``t`` about an axis (target frame) in even steps
    and refining each by the batched ICP at ``voxel``.
    """
    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    rot, trans, _ = _axis_turns(t, axis, point, preset.sweep_steps)
    pts = _subsample(s_lvl.points, 4 * preset.search_points, rng)
    grid = t_lvl.grid(voxel / 2.0, 3.0 * voxel)
    taus = voxel * np.array([3.0, 2.0, 2.0, 2.0, 1.5, 1.5, 1.5, 1.5])
    rot, trans, score = _chunked_icp(rot[1:], trans[1:], pts, t_lvl, grid, taus, score_tau)
    order = np.argsort(-score)
    poses = np.zeros((len(order), 4, 4))
    poses[:, :3, :3] = rot[order]
    poses[:, :3, 3] = trans[order]
    poses[:, 3, 3] = 1.0
    scale = max(src.diagonal, tgt.diagonal)
    return _distinct(poses, s_lvl.points.mean(axis=0), preset, scale)[: preset.hypotheses]


def _sweep_margin(
    src: _Cloud, tgt: _Cloud, t: NDArray[np.float64], axis: NDArray[np.float64], point: NDArray[np.float64],
    voxel: float, preset: RegistrationPreset, rng: np.random.Generator, score_tau: float,
) -> tuple[float, float]:
    """Quality margin of ``t`` over the same pose turned rigidly about a weak axis (no
    refinement, so that a continuous symmetry cannot slide the competitors back
    onto ``t``), see :func:`_competitor_margin`.
    """
    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    rot, trans, deg = _axis_turns(t, axis, point, preset.sweep_steps)
    pts = _subsample(s_lvl.points, 4 * preset.search_points, rng)
    grid = t_lvl.grid(voxel / 2.0, 3.0 * voxel)
    tgt_p, tgt_n = t_lvl.padded
    _, part, hit = _batch_score(rot, trans, pts, tgt_p, tgt_n, grid, preset.icp_distance * voxel, score_tau)
    overlap = hit.mean(axis=1)
    both = hit & hit[0]
    n = both.sum(axis=1)
    own = (part[0] * both).sum(axis=1) / np.maximum(n, 1)
    theirs = (part * both).sum(axis=1) / np.maximum(n, 1)
    far = np.flatnonzero(deg >= preset.distinct_deg)
    others = [(overlap[k], own[k], theirs[k], int(n[k]), deg[k]) for k in far]
    return _competitor_margin(float(overlap[0]), others, int(hit[0].sum()))


def _subsample(points: NDArray[np.float64], n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    if len(points) <= n:
        return points
    return points[rng.choice(len(points), n, replace=False)]


def _pair_result(
    indices: tuple[int, int], t: NDArray[np.float64], sc: _Score, margin: float, second_deg: float,
    ok: bool, reason: str, start: float, method: str,
) -> PairResult:
    return PairResult(
        source=indices[0], target=indices[1], transform=t,
        overlap=max(sc.overlap_source, sc.overlap_target),
        overlap_source=sc.overlap_source, overlap_target=sc.overlap_target,
        rmse_mm=sc.rmse_mm, expected_rmse_mm=sc.expected_mm, normal_agreement=sc.normal_agreement,
        score=sc.score,
        margin=margin, second_rotation_deg=second_deg, verified=ok, reason=reason,
        seconds=time.perf_counter() - start, method=method,
    )


# ---------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------


def register_pair(
    source: ArrayLike,
    target: ArrayLike,
    *,
    source_normals: ArrayLike | None = None,
    target_normals: ArrayLike | None = None,
    preset: str | RegistrationPreset = "standard",
    initial: ArrayLike | None = None,
    seed: int = 0,
) -> PairResult:
    """Register two partial point clouds without an initial guess, and verify the result.

    Parameters
    ----------
    source, target
        ``(N, 3)`` points in mm.  At least ``MIN_POINTS``, finite, spanning
        a volume (not all on a line or in a plane).
    source_normals, target_normals
        Optional ``(N, 3)`` outward normals (e.g. oriented toward the sensor);
        estimated when missing.
    preset
        ``draft``, ``standard``, ``reference`` or a :class:`RegistrationPreset`.
    initial
        Optional 4 x 4 initial guess (source -> target): skips the global search
        and only refines and verifies (no ambiguity check, ``margin`` is NaN).
    seed
        Seed of the random subsampling (results are reproducible).

    Returns
    -------
    PairResult
        ``transform`` maps source points into the target's frame; read
        ``verified`` and ``reason`` before trusting it.

    Examples
    --------
    An egg-shaped ellipsoid with a bump (no symmetry), turned and shifted:

    >>> rng = np.random.default_rng(0)
    >>> d = rng.normal(size=(3000, 3)); d /= np.linalg.norm(d, axis=1, keepdims=True)
    >>> bump = 1 + 0.3 * np.exp(-8 * np.sum((d - [0.5, 0.7, 0.5]) ** 2, axis=1))
    >>> pts = d * [30, 20, 12] * ((1 + 0.2 * d[:, 0]) * bump)[:, None]
    >>> turn = np.eye(4); turn[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]; turn[:3, 3] = [5, 0, 2]
    >>> res = register_pair(pts, transform_points(turn, pts), preset="draft")
    >>> rot_deg, shift_mm = pose_difference(res.transform, turn, pts)
    >>> res.verified, rot_deg < 0.05, shift_mm < 0.05
    (True, True, True)
    """
    p = registration_preset(preset)
    src = _as_cloud(source, source_normals, "source")
    tgt = _as_cloud(target, target_normals, "target")
    scale = _pair_scale(src, tgt)
    rng = np.random.default_rng(seed)
    if initial is None:
        return _register(src, tgt, scale, p, rng, (0, 1))
    t0 = _as_transform(initial, "initial")
    return _refine_and_check(src, tgt, scale, p, t0, (0, 1), time.perf_counter(), "initial", None)


def _as_transform(t: ArrayLike, name: str) -> NDArray[np.float64]:
    m = np.asarray(t, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise RegistrationError(f"{name} must be a finite 4 x 4 rigid transform, got shape {m.shape}")
    r = m[:3, :3]
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) <= 0:
        raise RegistrationError(f"{name} is not a rigid transform (its 3 x 3 block is not a rotation)")
    return m


def _refine_and_check(
    src: _Cloud, tgt: _Cloud, scale: float, preset: RegistrationPreset, t0: NDArray[np.float64],
    indices: tuple[int, int], start: float, method: str, first_distance: float | None,
    picks: tuple[NDArray[np.float64], NDArray[np.float64], float] | None = None,
) -> PairResult:
    """ICP from a given pose, then the checks (no competing hypotheses).

    With ``picks`` (source points, target points, their Kabsch RMS): where the
    fit leaves one rotation free (a surface of revolution turns about its
    axis without changing the fit), the angle about that axis is taken from
    the picks; and the result is refused if it moved the picks apart (the
    clouds do not confirm them).
    """
    levels = _pyramid(preset, scale, src, tgt)
    t = _icp_pyramid(src, tgt, preset, t0, levels, first_distance)
    fine = levels[-1]
    extra = ""
    if picks is not None:
        on_s, on_t, rms0 = picks
        weak = _weak_axis(src.level(fine), tgt.level(fine), t, fine, preset)
        if weak is not None and not isinstance(weak, str):
            t = _turn_to_picks(t, weak[0], weak[1], on_s, on_t)
        rms = float(np.sqrt(np.mean(np.sum((transform_points(t, on_s) - on_t) ** 2, axis=1))))
        allowed = max(3.0 * rms0, 2.0 * fine)
        if rms > allowed:
            extra = (f"the fit moved the picked points {rms:.3g} mm apart (more than {allowed:.3g} mm): "
                     "the clouds do not confirm the picks")
    tau_s = _score_scale(src, tgt, fine, preset)
    sc = _scored([_evaluate(src, tgt, t, fine, preset)], tau_s)[0]
    ok, reason = _verdict(sc, math.nan, math.nan, fine, preset)
    if extra:
        ok, reason = False, extra if ok else f"{reason}; {extra}"
    return _pair_result(indices, t, sc, math.nan, math.nan, ok, reason, start, method)


def _turn_to_picks(
    t: NDArray[np.float64], axis: NDArray[np.float64], point: NDArray[np.float64],
    on_s: NDArray[np.float64], on_t: NDArray[np.float64],
) -> NDArray[np.float64]:
    """``t`` turned about an axis (target frame) by the angle that best maps the picked
    source points onto the picked target points (closed form: the components
    across the axis, ``phi = atan2(sum u . (p x q), sum p . q)``).
    """
    p = transform_points(t, on_s) - point
    q = on_t - point
    p -= np.outer(p @ axis, axis)
    q -= np.outer(q @ axis, axis)
    phi = math.atan2(float(np.sum(np.cross(p, q) @ axis)), float(np.sum(p * q)))
    turn = np.eye(4)
    turn[:3, :3] = _rodrigues(phi * axis[None, :])[0]
    turn[:3, 3] = point - turn[:3, :3] @ point
    return turn @ t


def register_from_picks(
    source_points: ArrayLike,
    target_points: ArrayLike,
    source: ArrayLike | None = None,
    target: ArrayLike | None = None,
    *,
    source_normals: ArrayLike | None = None,
    target_normals: ArrayLike | None = None,
    preset: str | RegistrationPreset = "standard",
) -> PairResult:
    """Manual fallback: picked point pairs -> rigid transform, refined by ICP on the clouds.

    Parameters
    ----------
    source_points, target_points
        ``(M, 3)`` picked points (mm), ``M >= 3`` pairs in the same order,
        not collinear.
    source, target
        The clouds the points were picked on.  With them the Kabsch estimate
        is refined by the ICP pyramid and verified (overlap, residual,
        normals); without them the result is the Kabsch fit alone, reported
        unverified.
    source_normals, target_normals, preset
        As in :func:`register_pair`.

    Returns
    -------
    PairResult
        ``method`` is ``"picks"``; ``margin`` is NaN (no competing hypotheses).

    Examples
    --------
    Four picks on a torus (symmetric, so only picks can register it), off by 0.5 mm:

    >>> rng = np.random.default_rng(1)
    >>> u, v = rng.uniform(0, 2 * np.pi, (2, 1500))
    >>> pts = np.stack([30 * np.cos(u), 15 * np.sin(u) * np.cos(v), 10 * np.sin(v) * (1.3 + np.cos(u))], 1)
    >>> turn = np.eye(4); turn[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]; turn[:3, 3] = [5, 0, 2]
    >>> picks = pts[[0, 100, 200, 300]]
    >>> res = register_from_picks(picks, transform_points(turn, picks) + 0.5, pts,
    ...                           transform_points(turn, pts), preset="draft")
    >>> rot_deg, shift_mm = pose_difference(res.transform, turn, pts)
    >>> res.verified, rot_deg < 0.05, shift_mm < 0.05
    (True, True, True)
    """
    start = time.perf_counter()
    p = registration_preset(preset)
    t0, rms = rigid_from_picks(source_points, target_points)
    if source is None or target is None:
        if source is not None or target is not None:
            raise RegistrationError("give both clouds (source and target) or neither")
        nan = math.nan
        sc = _Score(nan, nan, rms, nan, nan)
        return _pair_result(
            (0, 1), t0, sc, nan, nan, False,
            f"not refined: no clouds given (Kabsch fit of the picks, RMS {rms:.3g} mm)", start, "picks",
        )
    src = _as_cloud(source, source_normals, "source")
    tgt = _as_cloud(target, target_normals, "target")
    scale = _pair_scale(src, tgt)
    first = max(3.0 * rms, p.search_voxel * scale)
    on_s = np.asarray(source_points, dtype=np.float64)
    on_t = np.asarray(target_points, dtype=np.float64)
    return _refine_and_check(src, tgt, scale, p, t0, (0, 1), start, "picks", first, (on_s, on_t, rms))


def _stability(
    src: _Level, tgt: _Level, t: NDArray[np.float64], tau: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    """Eigen-analysis of the point-to-plane information matrix at a pose.

    Gelfand, Ikemoto, Rusinkiewicz & Levoy, "Geometrically stable sampling for
    the ICP algorithm" (3DIM 2003): with rows ``[(x - c) x n / L, n]`` (``c``
    the centroid of the matched points, ``L`` their RMS radius), a small
    eigenvalue of ``J^T J / N`` relative to the largest is a motion that
    leaves the residuals nearly unchanged: a surface of revolution turns
    about its axis, a cylinder also slides along it, a sphere turns freely.

    Returns ascending eigenvalues ``(6,)``, eigenvectors ``(6, 6)`` (columns),
    the centre ``c`` (target frame) and ``L``.
    """
    x = transform_points(t, src.points)
    d, idx = tgt.tree.query(x, distance_upper_bound=tau, workers=-1)
    hit = np.isfinite(d)
    if hit.sum() < 6:
        return np.zeros(6), np.eye(6), x.mean(axis=0), 1.0
    xh = x[hit]
    nq = tgt.normals[idx[hit]]
    c = xh.mean(axis=0)
    arm = xh - c
    length = float(np.sqrt(np.mean(np.sum(arm * arm, axis=1))))
    jac = np.concatenate([np.cross(arm, nq) / length, nq], axis=1)
    evals, evecs = np.linalg.eigh(jac.T @ jac / len(jac))
    return evals, evecs, c, length


# ---------------------------------------------------------------------------
# Several passes: pairs, pose graph
# ---------------------------------------------------------------------------


def register_passes(
    clouds: Sequence[ArrayLike],
    normals: Sequence[ArrayLike | None] | None = None,
    *,
    preset: str | RegistrationPreset = "standard",
    pairs: str = "all",
    picks: Mapping[tuple[int, int], tuple[ArrayLike, ArrayLike]] | None = None,
    names: Sequence[str] | None = None,
    seed: int = 0,
) -> RegistrationResult:
    """Register several passes into the frame of the first, with a pose graph over all pairs.

    Parameters
    ----------
    clouds
        One ``(N_k, 3)`` point cloud (mm) per pass, each in its own frame
        (e.g. the table frame of its placement).
    normals
        Optional outward normals per pass (``None`` entries allowed).
    preset
        ``draft``, ``standard``, ``reference`` or a :class:`RegistrationPreset`.
    pairs
        ``"all"``: every pair ``i < j`` (loop closures everywhere, the most
        robust); ``"sequential"``: ``(i, i + 1)`` and ``(n - 1, 0)``.
    picks
        Manual fallback per pair: ``{(i, j): (points_on_i, points_on_j)}``,
        three or more corresponding points picked on pass ``i`` and pass
        ``j``; that pair is registered from the picks (see
        :func:`register_from_picks`) instead of the global search.
    names
        Names of the passes for messages (default ``"pass 0"``, ...).
    seed
        Seed of the random subsampling.

    Returns
    -------
    RegistrationResult
        Per pass the 4 x 4 pose into pass 0's frame (or why it has none), every
        pairwise result (``source = j``, ``target = i``: the transform maps
        pass ``j`` into pass ``i``), and the pose-graph consistency.

    Examples
    --------
    >>> rng = np.random.default_rng(2)
    >>> d = rng.normal(size=(3000, 3)); d /= np.linalg.norm(d, axis=1, keepdims=True)
    >>> bump = 1 + 0.3 * np.exp(-8 * np.sum((d - [0.5, 0.7, 0.5]) ** 2, axis=1))
    >>> pts = d * [30, 20, 12] * ((1 + 0.2 * d[:, 0]) * bump)[:, None]
    >>> turn = np.eye(4); turn[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    >>> res = register_passes([pts, transform_points(turn, pts)], preset="draft")
    >>> res.all_registered, pose_difference(res.poses[1].transform, np.linalg.inv(turn))[0] < 0.05
    (True, True)
    """
    start = time.perf_counter()
    p = registration_preset(preset)
    n = len(clouds)
    if n == 0:
        raise RegistrationError("register_passes: no clouds given; pass one point cloud per pass")
    if names is None:
        names = [f"pass {k}" for k in range(n)]
    if len(names) != n:
        raise RegistrationError(f"names: {len(names)} names for {n} clouds")
    if normals is None:
        normals = [None] * n
    if len(normals) != n:
        raise RegistrationError(f"normals: {len(normals)} entries for {n} clouds (use None where missing)")
    prepared = [_as_cloud(c, nm, name) for c, nm, name in zip(clouds, normals, names)]
    scale = _pair_scale(*prepared)
    pair_list = _pair_list(n, pairs)
    picks = dict(picks or {})
    for key in picks:
        if key not in pair_list:
            if (key[1], key[0]) in pair_list:
                raise RegistrationError(
                    f"picks: give pair {key} as {(key[1], key[0])} (i < j) with (points_on_i, points_on_j)"
                )
            raise RegistrationError(f"picks: pair {key} is not one of the registered pairs {pair_list}")
    rng = np.random.default_rng(seed)
    results: list[PairResult] = []
    for i, j in pair_list:
        if (i, j) in picks:
            on_i, on_j = picks[(i, j)]
            t_start = time.perf_counter()
            t0, rms = rigid_from_picks(on_j, on_i)
            first = max(3.0 * rms, p.search_voxel * scale)
            res = _refine_and_check(prepared[j], prepared[i], scale, p, t0, (j, i), t_start, "picks", first,
                                    (np.asarray(on_j, dtype=np.float64), np.asarray(on_i, dtype=np.float64), rms))
        else:
            res = _register(prepared[j], prepared[i], scale, p, rng, (j, i))
        results.append(res)
    poses, consistency = _pose_graph(prepared, results, scale, p)
    return RegistrationResult(
        poses=tuple(poses), pairs=tuple(results), consistency=consistency, preset=p,
        seconds=time.perf_counter() - start,
    )


def _pair_list(n: int, pairs: str) -> list[tuple[int, int]]:
    if pairs == "all":
        return [(i, j) for i in range(n) for j in range(i + 1, n)]
    if pairs == "sequential":
        out = [(i, i + 1) for i in range(n - 1)]
        if n > 2:
            out.append((0, n - 1))
        return out
    raise RegistrationError(f"pairs must be 'all' or 'sequential', got {pairs!r}")


def _pose_graph(
    clouds: Sequence[_Cloud], results: Sequence[PairResult], scale: float, preset: RegistrationPreset
) -> tuple[list[PassPose], PoseGraphConsistency | None]:
    """Spanning tree of the verified pairs (best score first) for initial poses, then
    Open3D's global optimisation with the other verified pairs as loop closures.
    """
    import open3d as o3d

    n = len(clouds)
    good = sorted((r for r in results if r.verified), key=lambda r: -r.score)
    # Kruskal's maximum spanning tree (a loop over the few pairs)
    parent = list(range(n))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    tree: list[PairResult] = []
    for r in good:
        a, b = root(r.source), root(r.target)
        if a != b:
            parent[a] = b
            tree.append(r)
    # poses along the tree from pass 0 (pose maps a pass into pass 0's frame)
    pose: dict[int, NDArray[np.float64]] = {0: np.eye(4)}
    grown = True
    while grown:
        grown = False
        for r in tree:
            if r.target in pose and r.source not in pose:
                pose[r.source] = pose[r.target] @ r.transform
                grown = True
            elif r.source in pose and r.target not in pose:
                pose[r.target] = pose[r.source] @ np.linalg.inv(r.transform)
                grown = True
    nodes = sorted(pose)
    consistency = None
    if len(nodes) > 1:
        reg = o3d.pipelines.registration
        where = {k: m for m, k in enumerate(nodes)}
        graph = reg.PoseGraph()
        for k in nodes:
            graph.nodes.append(reg.PoseGraphNode(pose[k]))
        fine = _pyramid(preset, scale, *clouds)[-1]
        dist = preset.icp_distance * fine
        edges = [r for r in good if r.source in where and r.target in where]
        tree_ids = {id(r) for r in tree}
        for r in edges:
            info = reg.get_information_matrix_from_point_clouds(
                clouds[r.source].level(fine).pcd, clouds[r.target].level(fine).pcd, dist, r.transform
            )
            graph.edges.append(reg.PoseGraphEdge(
                where[r.source], where[r.target], r.transform, info, uncertain=id(r) not in tree_ids
            ))
        option = reg.GlobalOptimizationOption(
            max_correspondence_distance=dist, edge_prune_threshold=0.25, preference_loop_closure=1.0,
            reference_node=0,
        )
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            reg.global_optimization(
                graph, reg.GlobalOptimizationLevenbergMarquardt(),
                reg.GlobalOptimizationConvergenceCriteria(), option,
            )
        anchor = np.linalg.inv(np.asarray(graph.nodes[0].pose))
        for k in nodes:
            pose[k] = anchor @ np.asarray(graph.nodes[where[k]].pose)
        pose[0] = np.eye(4)  # the frame of pass 0, exactly
        rows = []
        for r, e in zip(edges, graph.edges):
            rel = np.linalg.inv(pose[r.target]) @ pose[r.source]
            rot, disp = pose_difference(rel, r.transform, clouds[r.source].level(fine).points)
            rows.append((r.source, r.target, rot, disp, float(e.confidence)))
        consistency = PoseGraphConsistency(
            max_rotation_deg=max(row[2] for row in rows),
            max_displacement_mm=max(row[3] for row in rows),
            edges=tuple(rows),
        )
    out = []
    for k in range(n):
        if k in pose:
            out.append(PassPose(k, pose[k], True, "ok"))
            continue
        tried = [r for r in results if k in (r.source, r.target)]
        why = "; ".join(f"pair {r.target}-{r.source}: {r.reason}" for r in tried if not r.verified)
        out.append(PassPose(
            k, None, False,
            f"{clouds[k].name} is not connected to {clouds[0].name} by verified pairs"
            + (f" ({why})" if why else ""),
        ))
    return out, consistency


def merge_passes(
    clouds: Sequence[ArrayLike],
    result: RegistrationResult,
    normals: Sequence[ArrayLike | None] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.int64]]:
    """All registered passes in the frame of pass 0.

    Parameters
    ----------
    clouds, normals
        The clouds (and optional normals) given to :func:`register_passes`.
    result
        Its result; passes without a pose are left out.

    Returns
    -------
    tuple
        ``(points, normals, pass_index)``: ``(M, 3)`` points, ``(M, 3)``
        rotated normals (None unless every registered pass has normals) and
        the ``(M,)`` pass index of each point.

    Examples
    --------
    >>> t = np.eye(4); t[:3, 3] = [1, 0, 0]
    >>> res = RegistrationResult((PassPose(0, np.eye(4), True, "ok"), PassPose(1, t, True, "ok")),
    ...                          (), None, PRESETS["draft"], 0.0)
    >>> pts, nrm, idx = merge_passes([np.zeros((1, 3)), np.zeros((2, 3))], res)
    >>> pts[:, 0].tolist(), nrm is None, idx.tolist()
    ([0.0, 1.0, 1.0], True, [0, 1, 1])
    """
    if len(clouds) != len(result.poses):
        raise RegistrationError(f"merge_passes: {len(clouds)} clouds for {len(result.poses)} poses")
    normals = list(normals) if normals is not None else [None] * len(clouds)
    pts, nrm, idx = [], [], []
    for k, (c, pose) in enumerate(zip(clouds, result.poses)):
        if not pose.registered or pose.transform is None:
            continue
        p = np.asarray(c, dtype=np.float64).reshape(-1, 3)
        pts.append(transform_points(pose.transform, p))
        idx.append(np.full(len(p), k, dtype=np.int64))
        nk = normals[k]
        nrm.append(None if nk is None else np.asarray(nk, dtype=np.float64).reshape(-1, 3) @ pose.transform[:3, :3].T)
    if not pts:
        return np.zeros((0, 3)), None, np.zeros(0, dtype=np.int64)
    all_n = None if any(x is None for x in nrm) else np.concatenate(nrm)  # type: ignore[arg-type]
    return np.concatenate(pts), all_n, np.concatenate(idx)
