"""Registration of several passes: every pair, then a pose graph into the frame of pass 0.

See docs/processing.md, section "Registration of passes".
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.geometry.registration.clouds import _as_cloud, _Cloud
from processing.geometry.registration.pairwise import _as_colours, _refine_and_check, _register
from processing.geometry.registration.photo_consistency import PointColours
from processing.geometry.registration.presets import RegistrationError, RegistrationPreset, registration_preset
from processing.geometry.registration.refinement import _pair_scale, _pyramid
from processing.geometry.registration.results import PairResult, PassPose, PoseGraphConsistency, RegistrationResult
from processing.geometry.registration.transforms import pose_difference, rigid_from_picks, transform_points

__all__ = ["merge_passes", "register_passes"]


def register_passes(
    clouds: Sequence[ArrayLike],
    normals: Sequence[ArrayLike | None] | None = None,
    *,
    preset: str | RegistrationPreset = "standard",
    pairs: str = "all",
    picks: Mapping[tuple[int, int], tuple[ArrayLike, ArrayLike]] | None = None,
    names: Sequence[str] | None = None,
    seed: int = 0,
    colours: Sequence[PointColours | ArrayLike | None] | None = None,
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
        Names of the passes for messages (default ``"pass 1"``, ``"pass 2"``, ...: messages count
        from 1, the arrays and ``picks`` from 0).
    seed
        Seed of the random subsampling.
    colours
        Optional colours per pass from posed photos (``None`` entries
        allowed), as ``source_colours`` of :func:`register_pair`: they
        decide a pair whose shape leaves a turn about a nearly free axis
        ambiguous.

    Returns
    -------
    RegistrationResult
        Per pass the 4 x 4 pose into pass 0's frame (or why it has none), every
        pairwise result (``source = j``, ``target = i``: the transform maps
        pass ``j`` into pass ``i``), and the pose-graph consistency.

    Raises
    ------
    RegistrationError
        No clouds; as many names or normals as clouds not given; a cloud
        that cannot be registered (see :func:`register_pair`); ``pairs``
        neither ``"all"`` nor ``"sequential"``; picks for a pair that is not
        registered or given as ``(j, i)``; bad picks (see
        :func:`rigid_from_picks`); an unknown preset.

    References
    ----------
    .. [1] Choi, S., Zhou, Q.-Y., Koltun, V. (2015). Robust reconstruction of
       indoor scenes. CVPR 2015. doi:10.1109/CVPR.2015.7299195

    Examples
    --------
    >>> from processing.geometry.registration import pose_difference, transform_points
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
        names = [f"pass {k + 1}" for k in range(n)]
    if len(names) != n:
        raise RegistrationError(f"names: {len(names)} names for {n} clouds")
    if normals is None:
        normals = [None] * n
    if len(normals) != n:
        raise RegistrationError(f"normals: {len(normals)} entries for {n} clouds (use None where missing)")
    prepared = [_as_cloud(c, nm, name) for c, nm, name in zip(clouds, normals, names)]
    if colours is None:
        colours = [None] * n
    if len(colours) != n:
        raise RegistrationError(f"colours: {len(colours)} entries for {n} clouds (use None where missing)")
    painted = [_as_colours(c, len(cl.points), f"colours of {name}") for c, cl, name in zip(colours, prepared, names)]
    scale = _pair_scale(*prepared)
    pair_list = _pair_list(n, pairs)
    picks = dict(picks or {})
    for key in picks:
        if key not in pair_list:
            if (key[1], key[0]) in pair_list:
                raise RegistrationError(
                    f"picks: give the pair {names[key[1]]} - {names[key[0]]} in that order, with the points on "
                    f"{names[key[1]]} first"
                )
            named = ", ".join(f"{names[i]} - {names[j]}" for i, j in pair_list)
            raise RegistrationError(f"picks: {_pair_name(names, key)} is not one of the registered pairs ({named})")
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
            res = _register(prepared[j], prepared[i], scale, p, rng, (j, i), (painted[j], painted[i]))
        results.append(res)
    poses, consistency = _pose_graph(prepared, results, scale, p)
    return RegistrationResult(
        poses=tuple(poses), pairs=tuple(results), consistency=consistency, preset=p,
        seconds=time.perf_counter() - start,
    )


def _pair_name(names: Sequence[str], key: tuple[int, int]) -> str:
    """A picked pair by its passes' names, or by its indices when they name no pass."""
    i, j = key
    if all(isinstance(k, int) and 0 <= k < len(names) for k in key):
        return f"the pair {names[i]} - {names[j]}"
    return f"the pair of indices {key}"


def _pair_list(n: int, pairs: str) -> list[tuple[int, int]]:
    """The pairs ``(i, j)`` to register: every pair, or neighbours in order and the closing pair."""
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
    """Poses of the passes from the verified pairs: a spanning tree, then Open3D's global optimisation.

    The maximum spanning tree of the verified pairs (best score first) gives
    the initial poses; the other verified pairs are loop closures.
    """
    good = sorted((r for r in results if r.verified), key=lambda r: -r.score)
    tree = _spanning_tree(len(clouds), good)
    pose = _tree_poses(tree)
    consistency = None
    if len(pose) > 1:
        consistency = _optimise_poses(clouds, good, tree, pose, scale, preset)
    return _pass_poses(clouds, results, pose), consistency


def _spanning_tree(n: int, good: Sequence[PairResult]) -> list[PairResult]:
    """Kruskal's maximum spanning tree of ``n`` passes over pairs sorted best first (a loop over the few pairs)."""
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
    return tree


def _tree_poses(tree: Sequence[PairResult]) -> dict[int, NDArray[np.float64]]:
    """Poses along the tree from pass 0 (a pose maps a pass into pass 0's frame)."""
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
    return pose


def _optimise_poses(
    clouds: Sequence[_Cloud], good: Sequence[PairResult], tree: Sequence[PairResult],
    pose: dict[int, NDArray[np.float64]], scale: float, preset: RegistrationPreset,
) -> PoseGraphConsistency:
    """Optimise the poses in place (Open3D pose graph, pass 0 fixed) and measure each edge's disagreement."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    nodes = sorted(pose)
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
    return _consistency(clouds, edges, graph, pose, fine)


def _consistency(
    clouds: Sequence[_Cloud], edges: Sequence[PairResult], graph: Any,
    pose: dict[int, NDArray[np.float64]], fine: float,
) -> PoseGraphConsistency:
    """Rotation and displacement between every edge's transform and its optimised nodes, with its confidence."""
    rows = []
    for r, e in zip(edges, graph.edges):
        rel = np.linalg.inv(pose[r.target]) @ pose[r.source]
        rot, disp = pose_difference(rel, r.transform, clouds[r.source].level(fine).points)
        rows.append((r.source, r.target, rot, disp, float(e.confidence)))
    return PoseGraphConsistency(
        max_rotation_deg=max(row[2] for row in rows),
        max_displacement_mm=max(row[3] for row in rows),
        edges=tuple(rows),
    )


def _pass_poses(
    clouds: Sequence[_Cloud], results: Sequence[PairResult], pose: dict[int, NDArray[np.float64]]
) -> list[PassPose]:
    """One :class:`PassPose` per pass: its pose, or why no verified pair connects it to pass 0."""
    out = []
    for k in range(len(clouds)):
        if k in pose:
            out.append(PassPose(k, pose[k], True, "ok"))
            continue
        tried = [r for r in results if k in (r.source, r.target)]
        why = "; ".join(f"{clouds[r.target].name} - {clouds[r.source].name}: {r.reason}"
                        for r in tried if not r.verified)
        out.append(PassPose(
            k, None, False,
            f"{clouds[k].name} is not connected to {clouds[0].name} by verified pairs"
            + (f" ({why})" if why else ""),
        ))
    return out


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

    Raises
    ------
    RegistrationError
        Not one cloud per pose of ``result``.

    Examples
    --------
    >>> from processing.geometry.registration import PRESETS
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
