"""Registration of one pair of clouds: automatic (global search), from an initial pose, or from picks.

See docs/processing.md, section "Registration of passes".
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.geometry.registration.clouds import _as_cloud, _check_search_level, _Cloud, _Level
from processing.geometry.registration.global_search import _global_search
from processing.geometry.registration.photo_consistency import (
    MIN_SHARED_POINTS,
    ColourTurn,
    PointColours,
    colour_classes,
    colour_turn_sd_deg,
    photo_ids,
    revolution_axis,
    turn_by_colour,
)
from processing.geometry.registration.presets import RegistrationError, RegistrationPreset, registration_preset
from processing.geometry.registration.refinement import (
    _evaluate,
    _icp_pyramid,
    _pair_result,
    _pair_scale,
    _pyramid,
    _refine_distinct,
    _Score,
    _score_scale,
    _scored,
    _settle,
    _short_of,
    _verdict,
)
from processing.geometry.registration.results import PairResult
from processing.geometry.registration.symmetry import (
    _axis_sweep,
    _by_evidence,
    _Competitor,
    _competitors,
    _decision,
    _refined_competitor,
    _sweep_margin,
    _weak_axis,
)
from processing.geometry.registration.transforms import (
    _rodrigues,
    _rotation_angle_deg,
    rigid_from_picks,
    transform_points,
)
from processing.geometry.registration.turn_uncertainty import _turn_spread

__all__ = ["register_from_picks", "register_pair"]


def register_pair(
    source: ArrayLike,
    target: ArrayLike,
    *,
    source_normals: ArrayLike | None = None,
    target_normals: ArrayLike | None = None,
    preset: str | RegistrationPreset = "standard",
    initial: ArrayLike | None = None,
    seed: int = 0,
    source_colours: PointColours | ArrayLike | None = None,
    target_colours: PointColours | ArrayLike | None = None,
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
    source_colours, target_colours
        Optional colours of the points from posed photos: ``(N, 3)`` linear
        RGB (NaN where unseen) or a
        :class:`~processing.geometry.registration.photo_consistency.PointColours`
        that also gives the lamp direction and camera centre per point (then,
        with normals, highlights and grazing views are dropped).  Used only
        when the shape leaves the turn about a nearly free axis ambiguous:
        the turn is then decided by the points' colour classes if their
        evidence reaches ``min_evidence`` (``decided_by`` is ``"colour"``).

    Returns
    -------
    PairResult
        ``transform`` maps source points into the target's frame; read
        ``verified`` and ``reason`` before trusting it.

    Raises
    ------
    RegistrationError
        A cloud that is not ``(N, 3)``, has fewer than ``MIN_POINTS``
        points, NaN or infinite points, lies on a line or in a plane, or
        normals of another shape; an unknown preset; an ``initial`` that is
        not a rigid transform.

    References
    ----------
    .. [1] Besl, P. J., McKay, N. D. (1992). A method for registration of 3-D
       shapes. IEEE TPAMI 14(2), 239-256. doi:10.1109/34.121791
    .. [2] Chen, Y., Medioni, G. (1992). Object modelling by registration of
       multiple range images. Image and Vision Computing 10(3), 145-155.
       doi:10.1016/0262-8856(92)90066-C
    .. [3] Rusu, R. B., Blodow, N., Beetz, M. (2009). Fast point feature
       histograms (FPFH) for 3D registration. ICRA 2009.
       doi:10.1109/ROBOT.2009.5152473
    .. [4] Alexa, M. (2022). Super-Fibonacci spirals: fast, low-discrepancy
       sampling of SO(3). CVPR 2022.
    .. [5] Gelfand, N., Ikemoto, L., Rusinkiewicz, S., Levoy, M. (2003).
       Geometrically stable sampling for the ICP algorithm. 3DIM 2003.

    Examples
    --------
    An egg-shaped ellipsoid with a bump (no symmetry), turned and shifted:

    >>> from processing.geometry.registration import pose_difference, transform_points
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
    colours = _as_colours(source_colours, len(src.points), "source_colours"), \
        _as_colours(target_colours, len(tgt.points), "target_colours")
    if initial is None:
        for cloud in (src, tgt):
            _check_search_level(cloud, p.search_voxel * scale, scale)
        return _register(src, tgt, scale, p, rng, (0, 1), colours)
    t0 = _as_transform(initial, "initial")
    return _refine_and_check(src, tgt, scale, p, t0, (0, 1), time.perf_counter(), "initial", None)


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

    Raises
    ------
    RegistrationError
        Picks that are not ``(M, 3)``, fewer than 3 pairs, unequal in number,
        not finite or collinear; only one of the two clouds; a cloud that
        cannot be registered (see :func:`register_pair`); an unknown preset.

    References
    ----------
    .. [1] Kabsch, W. (1976). A solution for the best rotation to relate two
       sets of vectors. Acta Cryst. A32, 922-923. doi:10.1107/S0567739476001873
    .. [2] Umeyama, S. (1991). Least-squares estimation of transformation
       parameters between two point patterns. IEEE TPAMI 13(4), 376-380.
       doi:10.1109/34.88573
    .. [3] Chen, Y., Medioni, G. (1992). Object modelling by registration of
       multiple range images. Image and Vision Computing 10(3), 145-155.
       doi:10.1016/0262-8856(92)90066-C

    Examples
    --------
    Four picks on a torus (symmetric, so only picks can register it), off by 0.5 mm:

    >>> from processing.geometry.registration import pose_difference, transform_points
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


def _register(
    src: _Cloud,
    tgt: _Cloud,
    scale: float,
    preset: RegistrationPreset,
    rng: np.random.Generator,
    indices: tuple[int, int],
    colours: tuple[PointColours | None, PointColours | None] = (None, None),
) -> PairResult:
    """Automatic registration of a pair: global search, refinement, symmetry sweep, checks, colour."""
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
    sweep = _weak_axis(src.level(decide), tgt.level(decide), refined[best], decide, preset, nearly=10.0)
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
    centre = src.level(decide).points.mean(axis=0)
    # the pose settled where the poses are compared (its rivals are, as each is weighed, in _by_evidence)
    refined[best] = _settle(src, tgt, preset, refined[best], decide)
    scores[best] = _scored([_evaluate(src, tgt, refined[best], decide, preset)], tau_s)[0]
    memo: dict = {}  # each pose's evidence residuals, computed once for all the comparisons
    rivals = _competitors(src, tgt, decide, refined, scores, best, centre, scale, preset, memo)
    if sweep is not None and not isinstance(sweep, str):
        rivals += _turned_rivals(src, tgt, refined[best], scores[best], decide, centre, scale, preset, rng, tau_s,
                                 memo)
    t, sc_best, rivals = _by_evidence(src, tgt, decide, refined[best], scores[best], rivals, centre, scale, preset,
                                      memo)
    margin, second_deg, evidence, ambiguous = _decision(rivals, preset)
    if len(levels) > 1:
        t = _icp_pyramid(src, tgt, preset, t, levels[-1:], settled=True)
    # after the last ICP: where the shape leaves the turn free, the ICP would move it again
    decided_by, colour_note, colour_sd = "shape", "", math.nan
    if ambiguous and colours[0] is not None and colours[1] is not None:
        axis, spread = _pair_axis(src.level(decide), tgt.level(decide), t)
        if spread <= MAX_AXIS_SPREAD_DEG:
            t_c, colour_note = _turn_by_colour(src, tgt, colours[0], colours[1], t, axis, preset, int(rng.integers(1 << 30)))
            if t_c is not None:
                t, decided_by, ambiguous = t_c[0], "colour", False
                second_deg, evidence, colour_sd = t_c[1], t_c[2], t_c[3]
        else:
            colour_note = _no_revolution("colour cannot decide", spread)
    fine = levels[-1]
    sc = replace(_evaluate(src, tgt, t, fine, preset), score=sc_best.score)
    ok, reason = _verdict(sc, margin, second_deg, fine, preset, evidence, ambiguous)
    if colour_note and not (ok and decided_by == "colour"):
        reason = f"{reason}; {colour_note}"
    if weak_reason:
        reason = weak_reason if ok else f"{reason}; {weak_reason}"
        ok = False
    # a nearly symmetric pair: the turn about its axis rests on a small feature or on colour
    gated = _turn_gate(src, tgt, t, sweep, fine, preset, decided_by, colour_sd, (ok, reason))
    (t, sc, second_deg, evidence), (ok, reason, turn_deg), decided_by = _shape_turn_checked(
        src, tgt, colours, (t, sc, second_deg, evidence), gated, (ok, decided_by),
        (margin, sc_best, sweep, decide, fine, preset, rng))
    return replace(_pair_result(indices, t, sc, margin, second_deg, ok, reason, start, "global", evidence),
                   decided_by=decided_by, turn_uncertainty_deg=turn_deg)


def _shape_turn_checked(
    src: _Cloud, tgt: _Cloud, colours: tuple[PointColours | None, PointColours | None],
    pose: tuple[NDArray[np.float64], _Score, float, float], gated: tuple[bool, str, float],
    before: tuple[bool, str],
    context: tuple[float, _Score, tuple[NDArray[np.float64], NDArray[np.float64]] | str | None, float, float,
                   RegistrationPreset, np.random.Generator],
) -> tuple[tuple[NDArray[np.float64], _Score, float, float], tuple[bool, str, float], str]:
    """A pair after its passes' colours checked the turn its shape decided (:func:`_colour_placed_turn`).

    ``pose`` is the pair's (transform, score, second_deg, evidence),
    ``gated`` its (verified, reason, turn bound) after the turn's gate,
    ``before`` (verified before the gate, ``decided_by``) and ``context``
    (margin, best score, sweep, deciding and finest voxels, preset,
    generator).  Only a nearly symmetric pair whose shape decided the turn,
    which passed every other check and has colours, is checked.  Returns
    the pose, the gated verdict and ``decided_by``: the shape's, refused
    when the colours contradict it, or the colour turn's when its own bound
    verifies it or is the narrower (the colour bound is calibrated; on a
    shallow relief the shape's was not).
    """
    ok, reason, turn_deg = gated
    margin, sc_best, sweep, decide, fine, preset, rng = context
    cs, ct = colours
    if not (before[0] and before[1] == "shape" and math.isfinite(turn_deg)) or cs is None or ct is None:
        return pose, gated, before[1]
    placed, note = _colour_placed_turn(src, tgt, cs, ct, pose[0], turn_deg, decide, preset, rng)
    if placed is None:
        if note.startswith("shape and colour disagree"):
            ok, reason = False, (f"registered, but {note}; not verified: pick points to register this pair"
                                 if ok else f"{reason}; {note}")
        elif not ok:
            reason = f"{reason}; {note}"
        return pose, (ok, reason, turn_deg), "shape"
    t_c, second_c, evidence_c, sd_c = placed
    if preset.turn_sigmas * sd_c > max(preset.max_turn_deg, turn_deg):
        return pose, (ok, reason, turn_deg), "shape"
    sc_c = replace(_evaluate(src, tgt, t_c, fine, preset), score=sc_best.score)
    verdict_c = _verdict(sc_c, margin, pose[2], fine, preset, pose[3], False)
    ok_c, reason_c, turn_c = _turn_gate(src, tgt, t_c, sweep, fine, preset, "colour", sd_c, verdict_c)
    if ok_c:
        return (t_c, sc_c, second_c, evidence_c), (ok_c, reason_c, turn_c), "colour"
    if not ok:
        reason = (f"{reason}; placed by colour the turn is uncertain too (+-{turn_c:.2f} deg)"
                  if verdict_c[0] else f"{reason}; placed by colour the fit fails: {verdict_c[1]}")
    return pose, (ok, reason, turn_deg), "shape"


def _colour_placed_turn(
    src: _Cloud, tgt: _Cloud, cs: PointColours, ct: PointColours, t: NDArray[np.float64],
    shape_bound_deg: float, decide: float, preset: RegistrationPreset, rng: np.random.Generator,
) -> tuple[tuple[NDArray[np.float64], float, float, float] | None, str]:
    """The turn of a shape-decided pair decided by colour, when colour decides it and agrees with the shape.

    The shape's evidence chose the turn (its basin) and states its bound,
    ``shape_bound_deg`` (``turn_sigmas`` standard deviations).  Colour
    decides the turn on its own (a full sweep, :func:`_turn_by_colour`); it
    agrees when the two turns lie within their joint bound (the two bounds
    in quadrature).  Returns what :func:`_turn_by_colour` returns, or None
    and why not ("shape and colour disagree: ..." when they contradict each
    other).
    """
    axis, spread = _pair_axis(src.level(decide), tgt.level(decide), t)
    if spread > MAX_AXIS_SPREAD_DEG:
        return None, _no_revolution("colour cannot place the turn", spread)
    placed, why = _turn_by_colour(src, tgt, cs, ct, t, axis, preset, int(rng.integers(1 << 30)))
    if placed is None:
        return None, why.replace("colour cannot decide", "colour cannot place the turn", 1)
    apart = float(_rotation_angle_deg(t[:3, :3], placed[0][:3, :3]))
    joint = math.hypot(shape_bound_deg, preset.turn_sigmas * placed[3])
    if apart > joint:
        return None, (f"shape and colour disagree: colour turns the pair {apart:.2f} deg from the shape's turn, "
                      f"outside their joint bound (+-{joint:.2f} deg)")
    return placed, ""


def _turned_rivals(
    src: _Cloud, tgt: _Cloud, t: NDArray[np.float64], score: _Score, decide: float, centre: NDArray[np.float64],
    scale: float, preset: RegistrationPreset, rng: np.random.Generator, tau_s: float, memo: dict,
) -> list[_Competitor]:
    """The pose ``t`` turned rigidly about its weak axis, as a competitor, when it fits within the margin.

    The turned pose is judged at its best fit (refined at ``decide``), as the other competitors are.
    """
    again = _weak_axis(src.level(decide), tgt.level(decide), t, decide, preset, nearly=10.0)
    if again is None or isinstance(again, str):
        return []
    m2, _, turned = _sweep_margin(src, tgt, t, again[0], again[1], decide, preset, rng, tau_s)
    if turned is None or not m2 < preset.min_margin:
        return []
    t2 = _refined_competitor(src, tgt, turned, decide, preset)
    sc2 = _scored([_evaluate(src, tgt, t2, decide, preset)], tau_s)[0]
    return _competitors(src, tgt, decide, [t, t2], [score, sc2], 0, centre, scale, preset, memo)


def _turn_gate(
    src: _Cloud, tgt: _Cloud, t: NDArray[np.float64],
    sweep: tuple[NDArray[np.float64], NDArray[np.float64]] | str | None, voxel: float, preset: RegistrationPreset,
    decided_by: str, colour_sd: float, verdict: tuple[bool, str],
) -> tuple[bool, str, float]:
    """``(verified, reason, bound_deg)`` of a pair after its ``verdict`` (verified, reason) on every other check.

    Only a verified, nearly symmetric pair (colour decided its turn, or
    ``sweep`` is the weak axis it was swept about) is judged: the bound is
    ``turn_sigmas`` standard deviations of the turn about the axis, the
    colour turn's ``colour_sd`` (bootstrap and pixel sampling) when colour decided it, else
    :func:`~processing.geometry.registration.turn_uncertainty._turn_spread`
    about the sweep's axis at the finest level ``voxel``.  Other pairs keep
    their verdict, with a NaN bound.
    """
    colour = decided_by == "colour"
    if not verdict[0] or not (colour or isinstance(sweep, tuple)):
        return verdict[0], verdict[1], math.nan
    sd = colour_sd if colour or not isinstance(sweep, tuple) else _turn_spread(src, tgt, t, sweep[0], voxel, preset, sweep[1])[0]
    bound = preset.turn_sigmas * sd
    if bound <= preset.max_turn_deg:
        return True, "ok", bound
    if colour and math.isinf(sd):
        return False, ("registered by colour, but one photo holds every border of the decoration, so an error it "
                       "shares over all of them (its pose, its pixels) cannot be measured; not verified: photograph "
                       "the decoration from more table angles in both passes, or pick points to register this "
                       "pair"), bound
    what = "the decoration's borders" if colour else "the distinguishing feature (a boss, a chip)"
    finer = ("photograph the decoration with more pixels across it (the camera nearer or a longer lens: a "
             "photo locates a border only to within its pixel), " if colour else "")
    return False, (f"registered, but the turn about the symmetry axis is uncertain: +-{bound:.2f} deg "
                   f"({preset.turn_sigmas:g} sigma) > {preset.max_turn_deg:g} deg; not verified: {finer}scan more "
                   f"of {what} in both passes, with more profiles per revolution (the profiles that cross it hold "
                   f"the turn), or pick points to register this pair"), bound


#: Largest robust deviation (deg) of the normals from the meridian planes of a pair's axis for the
#: turn about it to be decided by colour (a turned object: 1-3 deg).
MAX_AXIS_SPREAD_DEG = 10.0


def _no_revolution(what: str, spread_deg: float) -> str:
    """Why colour was not used: the pair's normals leave the meridian planes of its best axis by ``spread_deg``."""
    return (f"{what}: the pair is no surface of revolution (its normals leave the meridian planes of the best "
            f"axis by {spread_deg:.1f} deg > {MAX_AXIS_SPREAD_DEG:g})")


def _pair_axis(
    s_lvl: _Level, t_lvl: _Level, t: NDArray[np.float64]
) -> tuple[tuple[NDArray[np.float64], NDArray[np.float64]], float]:
    """The axis of revolution of a fitted pair (target frame) and how well the two clouds fit it (deg).

    Fitted to the target's points and the source's mapped by ``t``, with
    their normals (:func:`~processing.geometry.registration.photo_consistency.revolution_axis`):
    on the simulated bowl within 0.12 deg and 0.07 mm of the true axis,
    where the information matrix's weak rotation is 1-2 deg and 1 mm off
    (partners' normals from another point, a rim's normals); turned by
    100 deg about an axis 2 deg off, a pose is 4 deg off.
    """
    x = np.concatenate([t_lvl.points, transform_points(t, s_lvl.points)])
    n = np.concatenate([t_lvl.normals, s_lvl.normals @ t[:3, :3].T])
    u, c, spread = revolution_axis(x, n)
    return (u, c), spread


def _as_colours(c: PointColours | ArrayLike | None, n: int, name: str) -> PointColours | None:
    """Checked per-point colours (and lamp and camera) of a cloud of ``n`` points, or None."""
    if c is None:
        return None
    pc = c if isinstance(c, PointColours) else PointColours(np.asarray(c, dtype=np.float64))
    for field in ("colours", "lamp_dirs", "camera_mm"):
        v = getattr(pc, field)
        if v is not None and np.shape(v) != (n, 3):
            raise RegistrationError(f"{name}: {field} must be (N, 3) with one row per point ({n}), "
                                    f"got shape {np.shape(v)}")
    if pc.pixel_mm is not None and np.shape(pc.pixel_mm) != (n,):
        raise RegistrationError(f"{name}: pixel_mm must be (N,) with one value per point ({n}), "
                                f"got shape {np.shape(pc.pixel_mm)}")
    return pc


def _turn_by_colour(
    src: _Cloud, tgt: _Cloud, cs: PointColours, ct: PointColours, t: NDArray[np.float64],
    axis: tuple[NDArray[np.float64], NDArray[np.float64]], preset: RegistrationPreset, seed: int,
) -> tuple[tuple[NDArray[np.float64], float, float, float] | None, str]:
    """The turn of ``t`` about a nearly free axis decided by the points' colour classes, or None and why not.

    Returns ``((pose, second_deg, sigma, turn_sd_deg), note)``, the last the
    turn's standard deviation (:func:`colour_turn_sd_deg`: the cells'
    bootstrap and the jackknife over the photos that coloured the points),
    when :func:`_colour_turn` finds one with at least the preset's evidence.
    """
    turn, why = _colour_turn(src, tgt, cs, ct, t, axis, preset, seed)
    if turn is None:
        return None, why
    return _colour_decision(turn, preset)


def _colour_decision(
    turn: ColourTurn, preset: RegistrationPreset,
) -> tuple[tuple[NDArray[np.float64], float, float, float] | None, str]:
    """What :func:`_turn_by_colour` returns for a found ``turn``: decided, or None and why not.

    Colour decides a turn only when the decoration of the two passes meets
    under it (at least :data:`~processing.geometry.registration.
    photo_consistency.MIN_SHARED_POINTS` of its points agree) and the turn
    has the preset's evidence over the best distinct one.  A turn that puts
    each pass's decoration where the other pass's photos did not see it
    disagrees with nothing, so it can agree best of all, and on its narrow
    basin with strong evidence; it is no evidence of the turn: the object
    might bear two such decorations, one seen by each pass.
    """
    if turn.shared_points < MIN_SHARED_POINTS:
        return None, (f"colour cannot decide: where the colours agree best the passes' decorations do not meet "
                      f"({turn.shared_points} of their points agree, < {MIN_SHARED_POINTS}): each falls where the "
                      "other pass's photos did not see it, as if the object bore two such decorations; photograph "
                      "the decoration from more table angles, or add a placement whose photos see it")
    if not turn.sigma >= preset.min_evidence:
        return None, (f"colour cannot decide: a turn {turn.second_deg:.1f} deg away agrees nearly as well "
                      f"(evidence {_short_of(turn.sigma)} sigma < {preset.min_evidence:g})")
    return (turn.transform, turn.second_deg, turn.sigma, colour_turn_sd_deg(turn)), ""


def _colour_turn(
    src: _Cloud, tgt: _Cloud, cs: PointColours, ct: PointColours, t: NDArray[np.float64],
    axis: tuple[NDArray[np.float64], NDArray[np.float64]], preset: RegistrationPreset, seed: int,
) -> tuple[ColourTurn | None, str]:
    """The best turn of ``t`` about ``axis`` (a direction and a point) by the colour classes, whatever its evidence.

    Partners are at most one sample spacing apart and, with normals, on the
    same face of a thin wall: the turn is located by the borders between
    classes, and a wider search does not only blur it but biases it (on the
    simulated plain bowl, given the right shape fit, partners three spacings
    apart turned the result by 0.5 to 1.8 deg on three of six pairs, with
    5.8 to 12.3 sigma of evidence; one spacing: within 0.42 deg).  Evidence
    cells are three times the partner distance; the photos that coloured
    the points are the jackknife's groups.  None and why when the colours
    are not two classes.
    """
    classes = colour_classes(src.points, cs, tgt.points, ct, source_normals=src.normals,
                             target_normals=tgt.normals)
    if not classes.usable:
        return None, f"colour cannot decide: {classes.why}"
    reach = max(src.spacing, tgt.spacing)
    turn = turn_by_colour(src.points, classes.source, tgt.points, classes.target, t, axis[0], axis[1],
                          max_distance_mm=reach, cell_mm=3.0 * reach, distinct_deg=preset.distinct_deg, seed=seed,
                          source_normals=src.normals, target_normals=tgt.normals,
                          source_groups=photo_ids(cs), target_groups=photo_ids(ct))
    return turn, ""


def _as_transform(t: ArrayLike, name: str) -> NDArray[np.float64]:
    """A checked finite 4 x 4 rigid transform."""
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
    """``t`` turned about an axis (target frame) by the angle that best maps the picked source points onto the targets.

    Closed form on the components across the axis:
    ``phi = atan2(sum u . (p x q), sum p . q)``.
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
