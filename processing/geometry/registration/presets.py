"""Registration presets (speed against accuracy) and the registration input error.

The method and the presets' values are described in docs/processing.md
(sections "Registration of passes" and "Presets").
"""

from __future__ import annotations

from dataclasses import dataclass

from processing.errors import InputError

__all__ = ["PRESETS", "RegistrationError", "RegistrationPreset", "registration_preset"]


class RegistrationError(InputError):
    """Input that cannot be registered; the message names the cloud or parameter and what to do."""


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
    min_evidence
        A competing pose within ``min_margin`` is ruled out when the evidence
        for the pose where the two differ reaches this many standard
        deviations (:func:`~processing.geometry.registration.pose_evidence.pose_evidence`:
        the significance of the log-likelihood ratio of the residuals that
        change between them, against the range noise, neighbouring points
        pooled into independent cells).
    min_normal_agreement
        Smallest accepted mean cosine between matched normals.
    max_partner_deg
        A point's partner in the other cloud in the ICP is its nearest point
        whose normal is within this angle of its own (of either sign when a
        cloud's normals are not oriented): across a thin wall the nearest
        point is often on the other face, whose normal points the other way.
        The scores leave out only partners more than ``180 -
        max_partner_deg`` away (the other face, oriented clouds).
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
    max_turn_deg
        A nearly symmetric pair (a weak rotation, or a turn decided by
        colour) is verified only when ``turn_sigmas`` standard deviations of
        its turn about the axis are at most this (deg): the evidence can pick
        the right turn while the refined angle is still this far off.
    turn_sigmas
        Standard deviations of the stated bound on the turn (2: about 95 %
        of pairs within it if the errors are Gaussian).

    Raises
    ------
    RegistrationError
        A parameter out of range (no rotation samples, voxel fractions
        outside (0, 1) or not from coarse to fine, no hypotheses, too few
        search points, ``search_keep`` outside (0, 1]).

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
    min_evidence: float = 5.0
    min_normal_agreement: float = 0.8
    max_partner_deg: float = 60.0
    distinct_deg: float = 8.0
    distinct_fraction: float = 0.03
    min_stability: float = 0.01
    min_voxel_spacing: float = 1.0
    score_scale: float = 0.5
    sweep_steps: int = 72
    max_turn_deg: float = 0.5
    turn_sigmas: float = 2.0

    def __post_init__(self) -> None:
        if not 0.0 < self.max_partner_deg < 90.0:
            raise RegistrationError(f"preset {self.name!r}: max_partner_deg must be in (0, 90) deg")
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

    Parameters
    ----------
    preset
        ``"draft"``, ``"standard"``, ``"reference"`` or a
        :class:`RegistrationPreset`.

    Returns
    -------
    RegistrationPreset
        The preset.

    Raises
    ------
    RegistrationError
        An unknown name.

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
