"""Results of a registration: one pair, the pose of one pass, the pose graph, several passes.

A transform ``T`` (4 x 4) of a pair maps points of its *source* cloud into
the frame of its *target* cloud: ``x_t = T @ x_s`` (mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from processing.geometry.registration.presets import RegistrationPreset

__all__ = ["PairResult", "PassPose", "PoseGraphConsistency", "RegistrationResult"]


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
    evidence_sigma
        Evidence for this pose over the competitor reported by
        ``second_rotation_deg``, where the two differ: the significance of
        their log-likelihood ratio in standard deviations of the range noise,
        neighbouring points pooled into independent cells
        (:func:`~processing.geometry.registration.pose_evidence.pose_evidence`).
        A competitor within ``min_margin`` is ruled out only by at least
        ``RegistrationPreset.min_evidence``.  NaN without competitors, for
        picks and a given initial pose.  When ``decided_by`` is ``"colour"``,
        the evidence of the colour classes for this turn over the best turn a
        distinct angle away
        (:func:`~processing.geometry.registration.photo_consistency.turn_by_colour`).
    decided_by
        ``"shape"``, or ``"colour"`` when the shape left the turn about a
        nearly free axis ambiguous and the points' colours decided it, or
        when the shape chose the turn and the colours, agreeing with it
        within the two turns' joint bound, placed it (their own bound
        verifying it, or narrower than the shape's; the evidence and
        competing turn are then the colours').
    turn_uncertainty_deg
        For a nearly symmetric pair that passed every other check, the
        stated bound on its turn about the symmetry axis:
        ``RegistrationPreset.turn_sigmas`` standard deviations (deg), from
        the fit's residuals and refits
        (:mod:`~processing.geometry.registration.turn_uncertainty`) or, when
        colour decided the turn, from a bootstrap of its colour cells and
        the photos' pixel footprint at the colour borders.  The
        pair is verified only when it is at most ``max_turn_deg``.  NaN for
        other pairs.
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
    evidence_sigma: float = math.nan
    decided_by: str = "shape"
    turn_uncertainty_deg: float = math.nan

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (the transform as nested lists).

        Returns
        -------
        dict
            One entry per attribute; the transform as nested lists, NaN and
            infinite numbers as None.
        """
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["transform"] = np.asarray(self.transform).tolist()
        for k, v in out.items():
            if isinstance(v, float) and not math.isfinite(v):
                out[k] = None
        return out


@dataclass(frozen=True)
class PassPose:
    """Final pose of one pass: ``transform`` maps the pass into the frame of pass 0.

    Attributes
    ----------
    index
        Index of the pass.
    transform
        4 x 4 rigid transform, pass frame -> frame of pass 0 (mm); ``None``
        when the pass is not connected to pass 0 by verified pairs.
    registered
        Whether the pass has a pose.
    reason
        ``"ok"`` or why the pass has no pose.
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
