"""Registration of nearly symmetric turned objects against the simulated world's truth.

For each turned object of :mod:`mocks.turned_objects` (the vase with a 1 mm boss, the bowl with a
0.1 mm inlaid motif, the plain bowl with a painted motif) and each station seed, two random
placements (2 and 3) are scanned as the station does (:func:`mocks.pass_cloud.simulated_pass`: the
station's sensor, placements and seeded 0.05 mm range noise; :data:`STEPS` profiles per revolution, ``kogei
capture``'s default, or ``--steps``) and
registered automatically (:func:`processing.geometry.registration.register_pair`, ``standard``).
The truth only scores: the pair's true transform is ``pose_2 @ inv(pose_3)``; a pair is *registered*
when it is verified and within 0.5 deg and 0.5 mm (largest displacement of the source points) of it,
*verified-but-wrong* when verified outside those limits, *ambiguous* when refused as ambiguous or
undetermined (a symmetric shape), *refused* for another reason.

For the vase, further seeds are scanned until ``--condition`` pairs (default 20) meet the target's
condition (:func:`feature_share`, from the truth, before registering), and only those further pairs are
registered, so that the rate under the condition rests on enough pairs.  With ``--sessions`` each of
those seeds is also registered as a session of three placements, as ``kogei process`` registers a
session (:func:`session_row`).

With ``--colour-bound`` only the plain bowl's colour step is measured, from the true shape fit, against
the standard deviation it states (:func:`colour_bound_rows`, :func:`colour_bound_summary`).

Run ``python -m bench.symmetric_bench [--quick] [--pairs N] [--condition N] [--sessions]``; prints one JSON object (the
last line).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bench.common import machine_description

__all__ = ["OBJECTS", "collect", "collect_colour", "collect_colour_bound", "collect_colour_end_to_end", "collect_seeds",
           "colour_bound_rows", "colour_bound_summary", "colour_section", "section"]

#: The objects and what should decide their pairs.
OBJECTS = {"vase": "shape (the boss)", "inlaid-bowl": "colour (the motif; 0.1 mm relief)",
           "plain-bowl": "colour only (painted motif)"}
#: Pose limits of a right pair (deg, mm), as the scan-processing benchmark's.
LIMIT_DEG, LIMIT_MM = 0.5, 0.5


#: The target's condition: a feature >= 10 x the range noise over at least this share of the overlap.
MIN_FEATURE_SHARE = 0.005
#: Profiles per revolution of the simulated passes: ``kogei capture``'s default scan.  The turn about a
#: turned object's axis is held by the profiles that cross its feature, so the scan's density is part of
#: what the rates below measure (``--steps 72`` gives the coarser scan the station's printed example takes).
STEPS = 200
#: Range noise of the simulated passes (mm), as :func:`mocks.pass_cloud.simulated_pass`'s default.
NOISE_MM = 0.05


def feature_share(name: str, a: Any, b: Any, partner_mm: float = 1.0) -> float:
    """Share of the pair's overlap where the vase's boss stands >= 10 x the range noise, from the truth.

    The overlap is, in each pass, the points with a point of the other pass (moved by the true
    transform) within ``partner_mm``; a point is on the feature when the boss's Gaussian
    (:data:`mocks.turned_objects.BOSS_HEIGHT_MM`, :data:`~mocks.turned_objects.BOSS_SIGMA_MM`, centred on
    the belly at azimuth 0, 30 mm up) is at least 10 x the noise high at its place on the belly.  The
    smaller of the two passes' shares is returned (the feature must be in both).
    """
    from scipy.spatial import cKDTree

    if name != "vase":
        return 0.0
    shares = []
    for p, q in ((a, b), (b, a)):
        moved = q.points @ (p.pose @ np.linalg.inv(q.pose))[:3, :3].T + (p.pose @ np.linalg.inv(q.pose))[:3, 3]
        d, _ = cKDTree(moved).query(p.points, distance_upper_bound=partner_mm)
        over = np.isfinite(d)
        on = _on_boss(p)
        shares.append(float(np.sum(on & over)) / max(int(over.sum()), 1))
    return min(shares)


def _object_frame(p: Any) -> NDArray[np.float64]:
    """A pass's points in the object's frame (from the truth)."""
    return np.asarray((p.points - p.pose[:3, 3]) @ p.pose[:3, :3])


def _on_boss(p: Any) -> NDArray[np.bool_]:
    """Which of a vase pass's points lie where the boss stands >= 10 x the range noise (from the truth)."""
    from mocks.turned_objects import BOSS_HEIGHT_MM, BOSS_SIGMA_MM

    radius = BOSS_SIGMA_MM * float(np.sqrt(2.0 * np.log(BOSS_HEIGHT_MM / (10.0 * NOISE_MM))))
    obj = _object_frame(p)
    arc = 26.0 * np.arctan2(obj[:, 1], obj[:, 0])
    return np.asarray(np.hypot(arc, obj[:, 2] - 30.0) < radius)


def hidden_feature_turn(name: str, a: Any, b: Any, step_deg: float = 2.0, min_turn_deg: float = 10.0) -> float | None:
    """A wrong turn about the vase's axis under which neither pass's boss lands on the other pass's surface.

    For each turn ``t`` (``min_turn_deg`` .. ``360 - min_turn_deg`` every ``step_deg``) the pair's
    competitor ``pose_a @ turn(t) @ inv(pose_b)`` is made from the truth; the boss's points of ``b`` are
    moved into ``a`` by it and those of ``a`` into ``b`` by its inverse.  A boss point *lands on* the other
    pass when that pass has a point within the boss's height + 1 mm.  Where no boss point of either pass
    lands, the two poses differ only where one pass or the other never measured the surface (in the pairs
    measured, surface facing down toward the table), and no evidence in shape can tell them apart.

    Returns
    -------
    float or None
        The turn (deg) with the fewest landing boss points if none lands, else None (every turn is
        contradicted by some boss point); None for objects other than the vase.
    """
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    from mocks.turned_objects import BOSS_HEIGHT_MM

    if name != "vase":
        return None
    counts = []
    turns = np.arange(min_turn_deg, 360.0 - min_turn_deg + 1e-9, step_deg)
    moving = [(b, a, 1.0), (a, b, -1.0)]
    objs = [_object_frame(p)[_on_boss(p)] for p, _, _ in moving]
    trees = [cKDTree(q.points) for _, q, _ in moving]
    for t in turns:
        n = 0
        for obj, tree, (_, q, sign) in zip(objs, trees, moving):
            turned = obj @ Rotation.from_euler("z", sign * t, degrees=True).as_matrix().T
            d, _ = tree.query(turned @ q.pose[:3, :3].T + q.pose[:3, 3], distance_upper_bound=BOSS_HEIGHT_MM + 1.0)
            n += int(np.isfinite(d).sum())
        counts.append(n)
    k = int(np.argmin(counts))
    return float(turns[k]) if counts[k] == 0 else None


def passes(name: str, seed: int, steps: int = STEPS) -> tuple[Any, Any]:
    """The pair's two passes of ``name`` at station seed ``seed`` (placements 2 and 3), ``steps`` profiles each."""
    from mocks.pass_cloud import simulated_pass
    from mocks.world import World

    world = World.turned(name)
    return simulated_pass(world, seed, 2, steps=steps), simulated_pass(world, seed, 3, steps=steps)


def pair_row(name: str, seed: int, scans: tuple[Any, Any] | None = None, steps: int = STEPS) -> dict[str, Any]:
    """One placement pair of ``name`` at station seed ``seed``, registered and scored (``scans``: its passes, if made)."""
    from processing.geometry.registration import pose_difference, register_pair

    a, b = scans if scans is not None else passes(name, seed, steps)
    res = register_pair(b.points, a.points, source_normals=b.normals, target_normals=a.normals,
                        preset="standard", seed=seed)
    rot, disp = pose_difference(res.transform, a.pose @ np.linalg.inv(b.pose), b.points)
    share = feature_share(name, a, b) if name == "vase" else 0.0
    feature = share >= MIN_FEATURE_SHARE
    right = rot <= LIMIT_DEG and disp <= LIMIT_MM
    outcome = _outcome(res, right)
    return {"object": name, "seed": seed, "outcome": outcome, "rotation_deg": round(float(rot), 3),
            **_turn_figures(res, a, b),
            "displacement_mm": round(float(disp), 3), "best_pose_right": bool(right),
            "evidence_sigma": None if not np.isfinite(res.evidence_sigma) else round(float(res.evidence_sigma), 1),
            "margin": round(float(res.margin), 4), "seconds": round(res.seconds, 1), "reason": res.reason,
            "feature_share": round(share, 4), "feature_in_both": feature,
            "hidden_turn_deg": hidden_feature_turn(name, a, b) if feature else None}


def _posed_colours(world: Any, p: Any, frame_size: tuple[int, int] | None, frame_step_deg: float = 30.0) -> Any:
    """A pass's colours from its posed frames (one every ``frame_step_deg`` of table angle, the station's 30 by
    default: ``kogei capture --camera-angles``), as a session with a camera calibration colours it."""
    from mocks.pass_cloud import pass_posed_frames
    from processing.geometry.registration.photo_consistency import colour_points

    angles = tuple(float(a) for a in np.arange(0.0, 360.0 - 1e-9, frame_step_deg))
    return colour_points(p.points, p.normals, *pass_posed_frames(world, p, angles, frame_size=frame_size))


def session_row(name: str, seed: int, steps: int = STEPS, coloured: bool = False,
                frame_size: tuple[int, int] | None = None, frame_step_deg: float = 30.0) -> dict[str, Any]:
    """A session of three placements (1, 2, 3) of ``name`` at station seed ``seed``, registered as ``kogei process`` does.

    Every pair is registered and the verified ones joined in a pose graph
    (:func:`processing.geometry.registration.register_passes`, ``standard``); each pass's pose is scored
    against the truth (right: within :data:`LIMIT_DEG` and :data:`LIMIT_MM` of ``pose_1 @ inv(pose_k)``).
    Placement 1 is the object's base pose (upright), 2 and 3 the pair rows' placements.  With
    ``coloured`` each pass is coloured from its posed frames as :func:`colour_end_to_end_row` colours
    it (``frame_size``: the station camera sampled finer).
    """
    from mocks.pass_cloud import simulated_pass
    from mocks.world import World
    from processing.geometry.registration import pose_difference, register_passes

    world = World.turned(name)
    c0 = time.process_time()
    scans = [simulated_pass(world, seed, k, steps=steps) for k in (1, 2, 3)]
    colours = [_posed_colours(world, p, frame_size, frame_step_deg) for p in scans] if coloured else None
    res = register_passes([p.points for p in scans], [p.normals for p in scans], preset="standard", seed=seed,
                          colours=colours)
    passes_out = []
    for k, pose in enumerate(res.poses):
        if pose.transform is None:
            passes_out.append({"placement": k + 1, "outcome": "not placed"})
            continue
        rot, disp = pose_difference(pose.transform, scans[0].pose @ np.linalg.inv(scans[k].pose), scans[k].points)
        right = rot <= LIMIT_DEG and disp <= LIMIT_MM
        passes_out.append({"placement": k + 1, "outcome": "right" if right else "wrong",
                           "rotation_deg": round(float(rot), 3), "displacement_mm": round(float(disp), 3)})
    pairs = [{"pair": f"{p.target + 1}-{p.source + 1}", "verified": bool(p.verified), "decided_by": p.decided_by,
              "evidence_sigma": None if not np.isfinite(p.evidence_sigma) else round(float(p.evidence_sigma), 1)}
             for p in res.pairs]
    return {"object": name, "seed": seed, "coloured": coloured, "frame_size": frame_size, "passes": passes_out,
            "pairs": pairs,
            "all_right": all(x["outcome"] == "right" for x in passes_out),
            "wrong": sum(x["outcome"] == "wrong" for x in passes_out), "cpu_s": round(time.process_time() - c0, 1)}


def _outcome(res: Any, right: bool) -> str:
    """A pair's outcome against the truth (``right``: within the limits)."""
    if res.verified:
        if not right:
            return "verified-but-wrong"
        return "resolved" if res.decided_by == "colour" else "registered"
    if "turn about the symmetry axis is uncertain" in res.reason:
        return "turn uncertain"
    if "ambiguous" in res.reason or "undetermined" in res.reason:
        return "ambiguous"
    return "refused"


def _turn_error_deg(transform: NDArray[np.float64], truth: NDArray[np.float64], axis: NDArray[np.float64]) -> float:
    """The signed turn (deg) about the unit ``axis`` by which ``transform`` differs from ``truth``."""
    from scipy.spatial.transform import Rotation

    rv = Rotation.from_matrix((transform @ np.linalg.inv(truth))[:3, :3]).as_rotvec()
    return float(np.degrees(rv @ axis))


def _turn_figures(res: Any, a: Any, b: Any) -> dict[str, Any]:
    """The true error of the pair's turn about the object's axis (deg) and the stated bound on it (deg)."""
    bound = res.turn_uncertainty_deg
    return {"turn_error_deg": round(_turn_error_deg(res.transform, a.pose @ np.linalg.inv(b.pose), a.pose[:3, 2]), 3),
            "turn_bound_deg": None if not np.isfinite(bound) else round(float(bound), 3)}


#: Most station seeds scanned in search of vase pairs that meet the condition.
MAX_SEEDS = 400


def collect(pairs: int, objects: list[str] | None = None, condition: int = 0, steps: int = STEPS,
            sessions: bool = False) -> dict[str, Any]:
    """Every object's ``pairs`` pairs (seeds 0 .. pairs - 1) and a summary per object.

    For the vase, further seeds are scanned until ``condition`` pairs in all meet the target's
    condition (:func:`feature_share`, from the truth, before registering); of those further seeds only
    the pairs that meet it are registered (``"extra": true``), the others are counted in
    ``vase_seeds_scanned`` and ``vase_shares``.  With ``sessions``, each vase seed whose pair meets the
    condition is also registered as a session of three placements (:func:`session_row`, ``"sessions"``).
    """
    rows, summary = [], {}
    scanned, shares = 0, []
    for name in objects or OBJECTS:
        mine = []
        for seed in range(pairs):
            t0 = time.perf_counter()
            r = pair_row(name, seed, steps=steps)
            r["wall_s"] = round(time.perf_counter() - t0, 1)
            print(json.dumps(r), file=sys.stderr, flush=True)
            mine.append(r)
        if name == "vase":
            scanned, shares = pairs, [r["feature_share"] for r in mine]
            seed = pairs
            while sum(r["feature_in_both"] for r in mine) < condition and seed < MAX_SEEDS:
                t0 = time.perf_counter()
                scans = passes(name, seed, steps)
                share = feature_share(name, *scans)
                scanned, seed = scanned + 1, seed + 1
                shares.append(round(share, 4))
                if share >= MIN_FEATURE_SHARE:
                    r = {**pair_row(name, seed - 1, scans), "extra": True, "wall_s": round(time.perf_counter() - t0, 1)}
                    print(json.dumps(r), file=sys.stderr, flush=True)
                    mine.append(r)
        rows += mine
        summary[name] = summarise(mine, name)
    sess = []
    for r in rows if sessions else []:
        if r["object"] == "vase" and r["feature_in_both"]:
            sess.append(session_row("vase", r["seed"], steps))
            print(json.dumps(sess[-1]), file=sys.stderr, flush=True)
    return {"machine": machine_description(), "load_1min": round(os.getloadavg()[0], 1),
            "pairs_per_object": pairs, "condition_pairs": condition, "steps": steps,
            "vase_seeds_scanned": scanned, "vase_shares": shares, "summary": summary, "rows": rows,
            **({"sessions": sess} if sessions else {})}


def summarise(rows: list[dict[str, Any]], name: str) -> dict[str, Any]:
    """The summary of ``name``'s rows (as :func:`collect` makes it)."""
    mine = [r for r in rows if r["object"] == name]
    count = {k: sum(r["outcome"] == k for r in mine) for k in ("registered", "verified-but-wrong", "turn uncertain", "ambiguous",
                                                              "refused")}
    ev = [r["evidence_sigma"] for r in mine if r["evidence_sigma"] is not None]
    return {"pairs": len(mine), **count, "best_pose_right": sum(r["best_pose_right"] for r in mine),
            "condition": sum(bool(r["feature_in_both"]) for r in mine),
            "registered_of_condition": sum(bool(r["feature_in_both"]) and r["outcome"] == "registered" for r in mine),
            "ambiguous_outside_condition": sum(not r["feature_in_both"] and r["outcome"] == "ambiguous" for r in mine),
            "evidence_sigma_median": round(statistics.median(ev), 1) if ev else None,
            "seconds_median": round(statistics.median(r["seconds"] for r in mine), 1)}


def _pct(n: int, d: int) -> str:
    return f"{n}/{d} ({100.0 * n / d:.0f} %)" if d else "-"


def _hidden_lines(cond: list[dict[str, Any]]) -> list[str]:
    """The paragraph on condition pairs whose boss a wrong turn hides from the other pass (none: no lines)."""
    known = [x for x in cond if "hidden_turn_deg" in x]
    if not known:
        return []
    hidden = [x for x in known if x["hidden_turn_deg"] is not None]
    seen = [x for x in known if x["hidden_turn_deg"] is None]
    ok = sum(x["outcome"] == "registered" for x in seen)
    return [
        f"Where shape can decide: in {len(hidden)} of the {len(known)} pairs meeting the condition a wrong turn "
        "about the axis "
        "leaves every boss point of each pass on surface the other pass never measured "
        "(`hidden_feature_turn`, from the truth: turns 10-350 deg every 2 deg; "
        + ("; ".join(f"seed {x['seed']}: {x['hidden_turn_deg']:.0f} deg, {x['outcome']}" for x in hidden) or "none")
        + "): the two poses differ only there, so no evidence in shape can separate them and the honest answer is "
        f"ambiguous.  Of the other {len(seen)} pairs {_pct(ok, len(seen))} were registered automatically.",
        "",
    ]


def _session_lines(sessions: list[dict[str, Any]] | None, cond: list[dict[str, Any]]) -> list[str]:
    """The paragraph on the condition seeds registered as sessions of three placements (none: no lines)."""
    if not sessions:
        return []
    by_seed = {x["seed"]: x for x in cond}
    ok = sum(x["all_right"] for x in sessions)
    wrong = sum(x["wrong"] for x in sessions)
    left = [x for x in sessions if by_seed.get(x["seed"], {}).get("outcome") != "registered"]
    cpu = statistics.median(x["cpu_s"] for x in sessions)
    rots = [p["rotation_deg"] for x in sessions for p in x["passes"] if "rotation_deg" in p]
    return [
        f"As sessions: each of the {len(sessions)} seeds whose pair meets the condition scanned in three placements "
        "(1, the vase upright, and the pair's 2 and 3) and registered as `kogei process` does (every pair, the "
        f"verified ones joined in a pose graph; `session_row`): all three passes right in {_pct(ok, len(sessions))} "
        f"sessions, {wrong} pass(es) placed wrong"
        + (f" (largest error {max(rots):.2f} deg)" if rots else "")
        + ("; the seeds whose pair 2-3 was not registered above: "
           + "; ".join(f"seed {x['seed']}: pairs "
                       + ", ".join(f"{p['pair']} {'verified' if p['verified'] else 'not'} ({p['evidence_sigma']} sigma)"
                                   for p in x["pairs"])
                       + f", passes {'all right' if x['all_right'] else 'not all right'}"
                       for x in left) if left else "")
        + f".  {cpu:.0f} s of CPU per session (median).",
        "",
    ]


def section(r: dict[str, Any]) -> list[str]:
    """The docs/BENCHMARKS.md section of a :func:`collect` result."""
    r_rows = r["rows"]
    # the table: the first ``pairs_per_object`` seeds of every object; the condition's rate: every vase pair
    # that meets it, the further seeds' included
    s = {name: summarise([x for x in r_rows if not x.get("extra")], name)
         for name in OBJECTS if any(x["object"] == name for x in r_rows)}
    cond = [x for x in r_rows if x["object"] == "vase" and x["feature_in_both"]]
    c_ok = sum(x["outcome"] == "registered" for x in cond)
    c_other = {k: sum(x["outcome"] == k for x in cond) for k in ("verified-but-wrong", "turn uncertain", "ambiguous",
                                                                 "refused")}
    c_ev = sorted(x["evidence_sigma"] for x in cond if x["evidence_sigma"] is not None)
    lines = [
        "## Nearly symmetric turned objects (registration by evidence)",
        "",
        f"`python -m bench.symmetric_bench --pairs {r['pairs_per_object']} --condition {r.get('condition_pairs', 0)}"
        + ("" if len(s) == len(OBJECTS) else "".join(f" --object {n}" for n in s))
        + ("" if r.get("steps", STEPS) == STEPS else f" --steps {r['steps']}")
        + (" --sessions" if r.get("sessions") else "")
        + f"` ({r['machine']}).  Each object of "
        "`mocks/turned_objects.py` ([simulator.md](simulator.md#turned-objects)) in two random placements (2 and 3) "
        f"per station seed, scanned as the station does (`mocks/pass_cloud.py`: {r.get('steps', 72)} profiles per "
        "revolution, 0.05 mm range noise) "
        "and registered automatically at `standard`; scored against the true placements "
        f"(right: within {LIMIT_DEG} deg and {LIMIT_MM} mm).  A competitor within the 5 % margin is ruled out only by "
        "at least 5 sigma of evidence where the two poses differ "
        "([processing.md](processing.md#nearly-symmetric-shapes-evidence)).",
        "",
        "| object | decided by | pairs | registered automatically | verified-but-wrong | turn uncertain | ambiguous "
        "| refused otherwise | best pose right (verified or not) | evidence (median, sigma) | s per pair (median) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, what in OBJECTS.items():
        if name not in s:
            continue
        x = s[name]
        lines.append(f"| `{name}` | {what} | {x['pairs']} | {_pct(x['registered'], x['pairs'])} | "
                     f"{x['verified-but-wrong']} | {x['turn uncertain']} | {_pct(x['ambiguous'], x['pairs'])} | "
                     f"{x['refused']} | "
                     f"{x['best_pose_right']} | {x['evidence_sigma_median']} | {x['seconds_median']} |")
    v = s["vase"]
    wrong_all = sum(x["outcome"] == "verified-but-wrong" for x in r_rows)
    plain = s.get("plain-bowl")
    extra = [x for x in r_rows if x.get("extra")]
    lines += [
        "",
        f"The target's condition (a feature >= 10 x the range noise over >= {100 * MIN_FEATURE_SHARE:.1f} % of the "
        "overlap) is measured per pair from the truth: the overlap is, in each pass, the points with a point of the "
        "other pass (moved by the true transform) within 1 mm; the feature is the part of the boss at least "
        f"{10 * NOISE_MM:.1f} mm high; the smaller of the two passes' shares counts.  It holds in "
        f"{v['condition']} of the first {v['pairs']} vase pairs and in no bowl pair (the inlaid motif stands 2 x the "
        "noise).  To state a rate, further station seeds are scanned (placements 2 and 3 each) "
        "until enough pairs meet the condition, measured before registering; only those are registered: "
        f"seeds 0-{r.get('vase_seeds_scanned', v['pairs']) - 1} scanned, {len(cond)} pairs meet the condition "
        f"({len(extra)} of them beyond the first {v['pairs']} seeds).",
        "",
        f"Targets: vase pairs meeting the condition >= 95 % registered automatically -- "
        f"**{'met' if cond and c_ok >= 0.95 * len(cond) else 'not met'}** ({_pct(c_ok, len(cond))}; "
        f"{c_other['turn uncertain']} turn uncertain, {c_other['ambiguous']} ambiguous, "
        f"{c_other['refused']} refused otherwise, "
        f"{c_other['verified-but-wrong']} verified-but-wrong; evidence "
        + (f"{c_ev[0]}-{c_ev[-1]} sigma, median {statistics.median(c_ev):.1f}" if c_ev else "-")
        + f"; of the first {v['pairs']} vase pairs {_pct(v['registered'], v['pairs'])}); "
        "0 verified-but-wrong over all pairs -- "
        f"**{'met' if wrong_all == 0 else 'not met'}**"
        + (f"; plain bowl ambiguous in shape -- {_pct(plain['ambiguous'], plain['pairs'])}" if plain else "")
        + "; resolved by colour once posed frames exist (100 %) -- see "
        "[end to end](#end-to-end-registering-a-pair-with-the-colours-of-posed-frames) "
        "([processing.md](processing.md#colour-where-shape-is-silent)).",
        "",
        *_hidden_lines(cond),
        *_session_lines(r.get("sessions"), cond),
        "Per vase pair meeting the condition (seed: outcome, evidence, feature's share of the overlap): "
        + "; ".join(f"{x['seed']}: {x['outcome']}, {x['evidence_sigma']} sigma, {100 * x['feature_share']:.2f} %"
                    + ("" if x["best_pose_right"] or x["outcome"] == "registered" else ", best pose wrong")
                    for x in cond) + ".  Outside it (first seeds): "
        + ("; ".join(f"{x['seed']}: {x['outcome']}, {x['evidence_sigma']} sigma, {100 * x['feature_share']:.2f} %"
                     + ("" if x["best_pose_right"] or x["outcome"] == "registered" else ", best pose wrong")
                     for x in r_rows if x["object"] == "vase" and not x["feature_in_both"]) or "none") + ".  "
        "The evidence is the stronger of two calibrated tests on true surface partners (a partner under the "
        "point, normals within 30 deg, not on its cloud's border): over every moving cell, and over only the cells "
        "where the two poses predict surfaces farther apart than the noise, the other cells calibrating its null "
        "([processing.md](processing.md#nearly-symmetric-shapes-evidence)).  Times are wall clock with other jobs "
        f"sharing the 2 cores (load {r.get('load_1min', '-')} at the end of the run).",
        "",
    ]
    return lines


def colour_row(name: str, seed: int, offset_deg: float = 100.0, steps: int = STEPS) -> dict[str, Any]:
    """One placement pair of ``name``: the turn about the axis decided by colour alone, scored against the truth.

    The shape fit is the true pose turned by ``offset_deg`` about the object's axis (every turn fits a
    plain bowl's shape equally); the colours are the station camera's frames every 30 deg
    (:func:`mocks.pass_cloud.pass_colour_views`, the camera's true pose standing in for a calibration).
    """
    from mocks.pass_cloud import pass_colour_views, simulated_pass
    from mocks.world import World
    from processing.geometry.registration import PointColours, pose_difference
    from processing.geometry.registration.photo_consistency import _turned, colour_classes, turn_by_colour

    world = World.turned(name)
    a, b = simulated_pass(world, seed, 2, steps=steps), simulated_pass(world, seed, 3, steps=steps)
    ca, cb = PointColours(*pass_colour_views(world, a)), PointColours(*pass_colour_views(world, b))
    truth = a.pose @ np.linalg.inv(b.pose)
    axis, point = a.pose[:3, 2], a.pose[:3, 3]
    start = _turned(truth, axis, point, np.radians([offset_deg]))[0]
    cl = colour_classes(b.points, cb, a.points, ca, source_normals=b.normals, target_normals=a.normals)
    row: dict[str, Any] = {"object": name, "seed": seed, "classes": cl.usable, "why": cl.why,
                           "otsu_eta": round(float(cl.effectiveness), 3), "class_gap": round(float(cl.gap), 3)}
    if not cl.usable:
        return {**row, "outcome": "ambiguous in colour", "sigma": None, "motif_shared": 0}
    # truth: points of the smaller class that meet the same class within 1 mm at the true pose
    from scipy.spatial import cKDTree

    minor = int(np.mean(cl.source[cl.source >= 0]) < 0.5)
    d, i = cKDTree(a.points).query(b.points @ truth[:3, :3].T + truth[:3, 3], distance_upper_bound=1.0)
    hit = np.isfinite(d)
    row["motif_shared"] = int(np.sum(hit & (cl.source == minor) & (cl.target[np.minimum(i, len(a.points) - 1)] == minor)))
    turn = turn_by_colour(b.points, cl.source, a.points, cl.target, start, axis, point,
                          max_distance_mm=1.0, cell_mm=3.0, seed=seed)
    rot, disp = pose_difference(turn.transform, truth, b.points)
    # the null on this pair's data: the source's classes given to randomly permuted points
    rng = np.random.default_rng(seed)
    null = [turn_by_colour(b.points, rng.permutation(cl.source), a.points, cl.target, start, axis, point,
                           max_distance_mm=1.0, cell_mm=3.0, seed=seed).sigma for _ in range(2)]
    row["shuffled_sigma"] = [round(z, 2) for z in null]
    right = rot <= LIMIT_DEG and disp <= LIMIT_MM
    accepted = turn.sigma >= 5.0
    outcome = ("resolved" if right else "verified-but-wrong") if accepted else "ambiguous in colour"
    return {**row, "outcome": outcome, "sigma": round(turn.sigma, 2), "second_deg": round(turn.second_deg, 1),
            "rotation_deg": round(float(rot), 3), "displacement_mm": round(float(disp), 3), "cells": turn.cells,
            "disagree_best": round(turn.disagree_best, 4), "disagree_second": round(turn.disagree_second, 4)}


def colour_bound_rows(seed: int, steps: int = STEPS, frame_size: tuple[int, int] | None = None,
                      offset_deg: float = 100.0, frame_step_deg: float = 30.0) -> list[dict[str, Any]]:
    """The plain bowl's colour turn and its stated spread, pairs 1-2, 1-3 and 2-3 of a session at ``seed``.

    As ``kogei process`` colours a session's passes (:func:`_posed_colours`, ``frame_size`` as
    :func:`colour_end_to_end_row`) and as :func:`processing.geometry.registration.register_pair`
    (``standard``) decides a pair's turn by colour (its private ``_colour_turn``), but from the true
    shape fit turned ``offset_deg`` about the bowl's axis, so that only the colour step is measured.
    Each row: the evidence (sigma), the true error of the turn about the axis (deg, signed) and the two
    parts of its stated standard deviation, the blocks' bootstrap and the jackknife over photos
    (:func:`colour_bound_summary` scores them).
    """
    from mocks.pass_cloud import simulated_pass
    from mocks.world import World
    from processing.geometry.registration import registration_preset
    from processing.geometry.registration.clouds import _as_cloud
    from processing.geometry.registration.pairwise import _colour_turn
    from processing.geometry.registration.photo_consistency import _turned

    world = World.turned("plain-bowl")
    preset = registration_preset("standard")
    scans = [simulated_pass(world, seed, k, steps=steps) for k in (1, 2, 3)]
    colours = [_posed_colours(world, p, frame_size, frame_step_deg) for p in scans]
    clouds = [_as_cloud(p.points, p.normals, f"placement {k + 1}") for k, p in enumerate(scans)]
    rows = []
    for i, j in ((0, 1), (0, 2), (1, 2)):
        truth = scans[i].pose @ np.linalg.inv(scans[j].pose)
        axis, point = scans[i].pose[:3, 2], scans[i].pose[:3, 3]
        start = _turned(truth, axis, point, np.radians([offset_deg]))[0]
        turn, why = _colour_turn(clouds[j], clouds[i], colours[j], colours[i], start, (axis, point), preset, seed)
        row: dict[str, Any] = {"seed": seed, "pair": f"{i + 1}-{j + 1}", "frame_size": frame_size,
                               "usable": turn is not None, "why": why}
        if turn is not None:
            row.update(sigma=round(float(turn.sigma), 2), error_deg=round(_turn_error_deg(turn.transform, truth, axis), 4),
                       bootstrap_sd_deg=round(float(turn.sigma_deg), 4), jackknife_sd_deg=round(float(turn.group_sd_deg), 4),
                       shared_points=int(turn.shared_points))
        rows.append(row)
    return rows


def colour_bound_summary(rows: list[dict[str, Any]], min_sigma: float = 5.0, limit_deg: float = LIMIT_DEG) -> dict[str, Any]:
    """How often the true colour turn lies within one and two stated standard deviations, per way of joining the parts.

    Over the rows of :func:`colour_bound_rows` that colour would decide (at least ``min_sigma`` of
    evidence, and the decorations meeting at the turn in at least
    :data:`~processing.geometry.registration.photo_consistency.MIN_SHARED_POINTS` points): for the
    stated rule (bootstrap and jackknife in quadrature, :func:`~processing.geometry.registration.
    photo_consistency.colour_turn_sd_deg`), the larger part, and each part alone, the share of true
    errors within 1 and 2 sd (68 and 95 % expected of an honest sd), the RMS of error / sd (1 expected),
    how many turns would be verified (2 sd <= ``limit_deg``) and how many of those lie further than
    ``limit_deg`` from the truth.

    Examples
    --------
    >>> rows = [{"usable": True, "sigma": 9.0, "error_deg": 0.09, "bootstrap_sd_deg": 0.06, "jackknife_sd_deg": 0.08},
    ...         {"usable": True, "sigma": 9.0, "error_deg": -0.6, "bootstrap_sd_deg": 0.15, "jackknife_sd_deg": 0.2},
    ...         {"usable": True, "sigma": 4.0, "error_deg": 3.0, "bootstrap_sd_deg": 0.1, "jackknife_sd_deg": 0.1}]
    >>> s = colour_bound_summary(rows)
    >>> s["pairs"], s["rules"]["quadrature"]["within_1sd"], s["rules"]["quadrature"]["within_2sd"]
    (2, 0.5, 0.5)
    >>> s["rules"]["quadrature"]["verified"], s["rules"]["quadrature"]["verified_wrong"]
    (2, 1)
    """
    from processing.geometry.registration.photo_consistency import MIN_SHARED_POINTS

    ok = [r for r in rows if r.get("usable") and r["sigma"] >= min_sigma
          and r.get("shared_points", MIN_SHARED_POINTS) >= MIN_SHARED_POINTS]
    err = np.abs([r["error_deg"] for r in ok])
    boot = np.array([r["bootstrap_sd_deg"] for r in ok])
    jack = np.nan_to_num(np.array([r["jackknife_sd_deg"] for r in ok], dtype=np.float64))
    rules = {"quadrature": np.hypot(boot, jack), "larger part": np.maximum(boot, jack), "bootstrap": boot,
             "jackknife": jack}
    out: dict[str, Any] = {"pairs": len(ok), "of": len(rows),
                           "rms_error_deg": round(float(np.sqrt(np.mean(err ** 2))), 3) if ok else None,
                           "largest_error_deg": round(float(err.max()), 3) if ok else None, "rules": {}}
    for name, sd in rules.items():
        z = err / np.maximum(sd, 1e-12)
        verified = 2.0 * sd <= limit_deg
        out["rules"][name] = {"within_1sd": round(float(np.mean(z <= 1.0)), 2) if ok else None,
                              "within_2sd": round(float(np.mean(z <= 2.0)), 2) if ok else None,
                              "rms_z": round(float(np.sqrt(np.mean(z ** 2))), 2) if ok else None,
                              "median_sd_deg": round(float(np.median(sd)), 3) if ok else None,
                              "verified": int(verified.sum()), "verified_wrong": int(np.sum(verified & (err > limit_deg)))}
    return out


def colour_end_to_end_row(name: str, seed: int, steps: int = STEPS,
                          frame_size: tuple[int, int] | None = None, frame_step_deg: float = 30.0) -> dict[str, Any]:
    """One placement pair of ``name`` registered automatically with the colours of its posed frames.

    Each pass is coloured from the station camera's frames every 30 deg as a session with a camera
    calibration colours it (:func:`mocks.pass_cloud.pass_posed_frames`, then
    :func:`processing.geometry.registration.photo_consistency.colour_points`: the pass's own points are
    the occluder), and :func:`processing.geometry.registration.register_pair` (``standard``) decides;
    scored against the truth as :func:`pair_row`.  ``frame_size`` (width, height): the station camera
    sampled finer than its 240 x 160 pixels.
    """
    from mocks.pass_cloud import simulated_pass
    from mocks.world import World
    from processing.geometry.registration import pose_difference, register_pair

    world = World.turned(name)
    a, b = simulated_pass(world, seed, 2, steps=steps), simulated_pass(world, seed, 3, steps=steps)
    ca, cb = _posed_colours(world, a, frame_size, frame_step_deg), _posed_colours(world, b, frame_size, frame_step_deg)
    res = register_pair(b.points, a.points, source_normals=b.normals, target_normals=a.normals, preset="standard",
                        seed=seed, source_colours=cb, target_colours=ca)
    truth = a.pose @ np.linalg.inv(b.pose)
    rot, disp = pose_difference(res.transform, truth, b.points)
    right = rot <= LIMIT_DEG and disp <= LIMIT_MM
    outcome = _outcome(res, right)
    return {"object": name, "seed": seed, "outcome": outcome, "decided_by": res.decided_by, **_turn_figures(res, a, b),
            "rotation_deg": round(float(rot), 3), "displacement_mm": round(float(disp), 3),
            "evidence_sigma": None if not np.isfinite(res.evidence_sigma) else round(float(res.evidence_sigma), 1),
            "rmse_mm": round(float(res.rmse_mm), 4), "seconds": round(res.seconds, 1), "reason": res.reason}


def collect_seeds(seeds: list[int], objects: list[str], end_to_end: bool = False, steps: int = STEPS,
                  frame_size: tuple[int, int] | None = None, sessions: bool = False,
                  frame_step_deg: float = 30.0) -> dict[str, Any]:
    """:func:`pair_row` of each object at the given seeds (:func:`colour_end_to_end_row` with ``end_to_end``).

    With ``sessions``: :func:`session_row` instead (coloured from posed frames with ``end_to_end``).
    """
    rows = []
    for name in objects:
        for seed in seeds:
            t0, c0 = time.perf_counter(), time.process_time()
            if sessions:
                r = session_row(name, seed, steps, coloured=end_to_end, frame_size=frame_size,
                                frame_step_deg=frame_step_deg)
            elif end_to_end:
                r = colour_end_to_end_row(name, seed, steps, frame_size, frame_step_deg)
            else:
                r = pair_row(name, seed, steps=steps)
            r.update(wall_s=round(time.perf_counter() - t0, 1), cpu_s=round(time.process_time() - c0, 1),
                     load_1min=round(os.getloadavg()[0], 1))
            print(json.dumps(r), file=sys.stderr, flush=True)
            rows.append(r)
    return {"machine": machine_description(), "steps": steps, "frame_size": frame_size,
            "frame_step_deg": frame_step_deg, "rows": rows}


def collect_colour_end_to_end(pairs: int, steps: int = STEPS, frame_size: tuple[int, int] | None = None) -> dict[str, Any]:
    """:func:`colour_end_to_end_row` for the plain bowl, seeds 0 .. pairs - 1."""
    rows = []
    for seed in range(pairs):
        r = colour_end_to_end_row("plain-bowl", seed, steps, frame_size)
        print(json.dumps(r), file=sys.stderr, flush=True)
        rows.append(r)
    return {"machine": machine_description(), "pairs_per_object": pairs, "steps": steps, "frame_size": frame_size,
            "rows": rows}


def collect_colour_bound(seeds: list[int], steps: int = STEPS, frame_size: tuple[int, int] | None = None,
                         frame_step_deg: float = 30.0) -> dict[str, Any]:
    """:func:`colour_bound_rows` of the given seeds and their :func:`colour_bound_summary`."""
    rows = []
    for seed in seeds:
        for r in colour_bound_rows(seed, steps, frame_size, frame_step_deg=frame_step_deg):
            print(json.dumps(r), file=sys.stderr, flush=True)
            rows.append(r)
    return {"machine": machine_description(), "steps": steps, "frame_size": frame_size,
            "frame_step_deg": frame_step_deg, "summary": colour_bound_summary(rows), "rows": rows}


def collect_colour(pairs: int, steps: int = STEPS) -> dict[str, Any]:
    """:func:`colour_row` for the plain bowl and the bare bowl, seeds 0 .. pairs - 1."""
    rows = []
    for name in ("plain-bowl", "plain-bowl:bare"):
        for seed in range(pairs):
            r = colour_row(name, seed, steps=steps)
            print(json.dumps(r), file=sys.stderr, flush=True)
            rows.append(r)
    return {"machine": machine_description(), "pairs_per_object": pairs, "steps": steps, "rows": rows}


def colour_section(r: dict[str, Any]) -> list[str]:
    """The docs/BENCHMARKS.md table of a :func:`collect_colour` result."""
    lines = ["| object | pairs | resolved by colour | verified-but-wrong | ambiguous in colour | evidence per pair (sigma) "
             "| motif points both passes share (truth) | shuffled classes (sigma) |",
             "|---|---|---|---|---|---|---|---|"]
    for name in ("plain-bowl", "plain-bowl:bare"):
        mine = [x for x in r["rows"] if x["object"] == name]
        k = {o: sum(x["outcome"] == o for x in mine) for o in ("resolved", "verified-but-wrong", "ambiguous in colour")}
        lines.append(f"| `{name}` | {len(mine)} | {_pct(k['resolved'], len(mine))} | {k['verified-but-wrong']} | "
                     f"{_pct(k['ambiguous in colour'], len(mine))} | "
                     + ", ".join("-" if x["sigma"] is None else f"{x['sigma']}" for x in mine) + " | "
                     + ", ".join(str(x["motif_shared"]) for x in mine) + " | "
                     + ", ".join("/".join(str(z) for z in x.get("shuffled_sigma", [])) or "-" for x in mine) + " |")
    return lines


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 pairs per object instead of --pairs")
    ap.add_argument("--pairs", type=int, default=10, help="placement pairs (station seeds) per object (default 10)")
    ap.add_argument("--condition", type=int, default=20,
                    help="scan further vase seeds until this many pairs meet the target's condition (default 20)")
    ap.add_argument("--colour", action="store_true",
                    help="only the turn of the plain and bare bowls decided by colour (given the right shape fit)")
    ap.add_argument("--object", action="append", choices=sorted(OBJECTS), default=None,
                    help="only this object (repeatable; default all; shape evidence only, but with --seeds "
                         "--colour-end-to-end: coloured from posed frames, default the plain bowl)")
    ap.add_argument("--colour-end-to-end", action="store_true",
                    help="only the plain bowl registered automatically with colours from its posed frames")
    ap.add_argument("--steps", type=int, default=STEPS,
                    help=f"profiles per revolution of the simulated passes (default {STEPS}, kogei capture's default)")
    ap.add_argument("--frame-size", type=lambda v: tuple(int(x) for x in v.lower().split("x")), default=None,
                    metavar="WxH", help="with --colour-end-to-end or --colour-bound: the station camera sampled at W x H pixels "
                                        "(default its 240 x 160)")
    ap.add_argument("--frame-step", type=float, default=30.0, metavar="DEG",
                    help="with --colour-bound or --seeds --colour-end-to-end: a frame every DEG of table angle "
                         "(default 30, kogei capture's default --camera-angles)")
    ap.add_argument("--colour-bound", action="store_true",
                    help="only the plain bowl's colour turn from the true shape fit, pairs 1-2, 1-3 and 2-3 of the --seeds "
                         "(default 0-23): its true error against its stated standard deviation (with --frame-size)")
    ap.add_argument("--sessions", action="store_true",
                    help="also register each vase seed meeting the condition as a session of three placements "
                         "(with --seeds: sessions of those seeds instead of pairs)")
    ap.add_argument("--seeds", type=lambda v: [int(x) for x in v.split(",")], default=None,
                    help="only these station seeds (comma-separated) of each --object, or of the plain bowl with "
                         "--colour-end-to-end; prints the rows")
    args = ap.parse_args(argv)
    n = 3 if args.quick else args.pairs
    if args.colour_bound:
        seeds = args.seeds if args.seeds is not None else list(range(24))
        print(json.dumps(collect_colour_bound(seeds, args.steps, args.frame_size, args.frame_step)))
        return
    if args.seeds is not None:
        objects = args.object or (["plain-bowl"] if args.colour_end_to_end else list(OBJECTS))
        print(json.dumps(collect_seeds(args.seeds, objects, args.colour_end_to_end, args.steps,
                                       args.frame_size, args.sessions, args.frame_step)))
        return
    if args.colour_end_to_end:
        print(json.dumps(collect_colour_end_to_end(n, args.steps, args.frame_size)))
        return
    print(json.dumps(collect_colour(n, args.steps) if args.colour else collect(n, args.object, args.condition, args.steps,
                                                                                args.sessions)))


if __name__ == "__main__":
    main()
