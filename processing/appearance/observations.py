"""Every (vertex, frame) sample of the camera signal with its noise and geometry, and its file.

:func:`observe` samples the linear, chart-calibrated images at the
projections of the vertices each frame sees
(:func:`~processing.appearance.visibility.visible_vertices`) and records the
geometry in M the reflectance fit needs: normal, view direction, the
direction to each lamp, the half-vector angle and the distance to the camera.
The result is stored sorted by vertex with CSR offsets
(``offsets[i]:offsets[i+1]`` are vertex ``i``'s observations).

:func:`write_observations` / :func:`read_observations` keep it in an ``.npz``
(``allow_pickle=False``); the reader trusts nothing: schema, version and every
array's dtype, shape, bounds and finiteness are checked.

References
----------
Lensch, H. P. A., Kautz, J., Goesele, M., Heidrich, W., Seidel, H.-P. (2003).
Image-based reconstruction of spatial appearance and geometric detail. ACM
TOG 22(2), 234-257. doi:10.1145/636886.636891
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.appearance.frame_poses import AppearanceError, FramePose
from processing.appearance.projection import mesh_arrays, project_points, raycasting_scene
from processing.appearance.visibility import visible_vertices
from processing.common.npz import read_npz

__all__ = ["Observations", "observe", "per_vertex_counts", "select_frames", "bilinear", "write_observations", "read_observations",
           "OBSERVATIONS_SCHEMA", "OBSERVATIONS_VERSION"]

OBSERVATIONS_SCHEMA = "kogei.observations"
OBSERVATIONS_VERSION = 1


@dataclass(frozen=True)
class Observations:
    """Observations of the mesh's vertices in the frames, sorted by vertex.

    Attributes
    ----------
    n_vertices
        Number of mesh vertices.
    frame_names
        ``(K,)`` names of the frames (``frame`` indexes them).
    lamp_names
        ``(L,)`` lamp names, the same lamps in every frame.
    offsets
        ``(n_vertices + 1,)`` int64 CSR offsets into the observation arrays.
    vertex, frame
        ``(n,)`` int32 vertex and frame index of each observation.
    uv_px
        ``(n, 2)`` float32 projected pixel position.
    signal, sigma
        ``(n, C)`` float32 sampled linear signal (bilinear) and its noise std.
    clipped
        ``(n,)`` bool: a channel in the 3 x 3 neighbourhood is at or above the clip level.
    normal, view_dir
        ``(n, 3)`` float32 unit normal and unit direction to the camera, M.
    light_dir
        ``(n, L, 3)`` float32 unit direction to each lamp, M.
    half_angle_deg
        ``(n, L)`` float32 angle between the normal and the half vector of view and light.
    distance_mm
        ``(n,)`` float32 distance from the vertex to the camera centre.
    """

    n_vertices: int
    frame_names: tuple[str, ...]
    lamp_names: tuple[str, ...]
    offsets: NDArray[np.int64]
    vertex: NDArray[np.int32]
    frame: NDArray[np.int32]
    uv_px: NDArray[np.float32]
    signal: NDArray[np.float32]
    sigma: NDArray[np.float32]
    clipped: NDArray[np.bool_]
    normal: NDArray[np.float32]
    view_dir: NDArray[np.float32]
    light_dir: NDArray[np.float32]
    half_angle_deg: NDArray[np.float32]
    distance_mm: NDArray[np.float32]

    def __len__(self) -> int:
        return int(len(self.vertex))

    def of_vertex(self, index: int) -> dict[str, NDArray[Any]]:
        """The observations of one vertex.

        Parameters
        ----------
        index
            Vertex index.

        Returns
        -------
        dict
            Array name -> that vertex's rows (views, not copies).
        """
        if not 0 <= int(index) < self.n_vertices:
            raise AppearanceError(f"vertex {index}: out of range 0..{self.n_vertices - 1}")
        a, b = int(self.offsets[index]), int(self.offsets[index + 1])
        return {name: getattr(self, name)[a:b] for name in _ROW_ARRAYS}


_ROW_ARRAYS = ("vertex", "frame", "uv_px", "signal", "sigma", "clipped", "normal", "view_dir", "light_dir",
               "half_angle_deg", "distance_mm")


def per_vertex_counts(obs: Observations) -> NDArray[np.int64]:
    """How many frames observe each vertex.

    Parameters
    ----------
    obs
        The observations.

    Returns
    -------
    ndarray
        ``(n_vertices,)`` int64.
    """
    return np.diff(obs.offsets)


def select_frames(obs: Observations, keep: ArrayLike) -> Observations:
    """The observations of some frames only (e.g. leaving held-out frames out of a fit).

    Parameters
    ----------
    obs
        The observations.
    keep
        ``(K,)`` bool per frame of ``obs.frame_names``: True to keep its observations.

    Returns
    -------
    Observations
        Same vertices, frames and lamps; only the rows of kept frames, still sorted by vertex.

    Raises
    ------
    AppearanceError
        ``keep`` does not hold one flag per frame.

    Examples
    --------
    >>> obs = Observations(2, ("a", "b"), (), np.array([0, 2, 3]), vertex=np.array([0, 0, 1], np.int32),
    ...     frame=np.array([0, 1, 1], np.int32), uv_px=np.zeros((3, 2), np.float32),
    ...     signal=np.zeros((3, 3), np.float32), sigma=np.ones((3, 3), np.float32), clipped=np.zeros(3, bool),
    ...     normal=np.zeros((3, 3), np.float32), view_dir=np.zeros((3, 3), np.float32),
    ...     light_dir=np.zeros((3, 0, 3), np.float32), half_angle_deg=np.zeros((3, 0), np.float32),
    ...     distance_mm=np.ones(3, np.float32))
    >>> select_frames(obs, [False, True]).offsets.tolist()
    [0, 1, 2]
    """
    flags = np.asarray(keep, dtype=bool).reshape(-1)
    if flags.size != len(obs.frame_names):
        raise AppearanceError(f"select_frames: keep has {flags.size} flags for {len(obs.frame_names)} frames; "
                              "give one per frame")
    rows = flags[obs.frame]
    cat = {name: getattr(obs, name)[rows] for name in _ROW_ARRAYS}
    offsets = np.zeros(obs.n_vertices + 1, dtype=np.int64)
    np.cumsum(np.bincount(cat["vertex"], minlength=obs.n_vertices), out=offsets[1:])
    return Observations(obs.n_vertices, obs.frame_names, obs.lamp_names, offsets, **cat)


def bilinear(image: NDArray[np.float32], uv_px: NDArray[np.float64]) -> NDArray[np.float32]:
    """Bilinear samples of an ``(H, W, C)`` image at pixel positions (pixel centres at integers).

    Parameters
    ----------
    image
        ``(H, W, C)``.
    uv_px
        ``(n, 2)`` (column, row), clamped to the image.

    Returns
    -------
    ndarray
        ``(n, C)`` float32.
    """
    h, w = image.shape[:2]
    u = np.clip(uv_px[:, 0], 0.0, w - 1.0)
    v = np.clip(uv_px[:, 1], 0.0, h - 1.0)
    u0 = np.minimum(np.floor(u).astype(np.intp), max(w - 2, 0))
    v0 = np.minimum(np.floor(v).astype(np.intp), max(h - 2, 0))
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    top = image[v0, u0] * (1 - fu) + image[v0, u1] * fu
    bottom = image[v1, u0] * (1 - fu) + image[v1, u1] * fu
    return (top * (1 - fv) + bottom * fv).astype(np.float32)


def _check_image(image: Any, frame: FramePose) -> NDArray[np.float32]:
    img = np.asarray(image, dtype=np.float32)
    img = img[..., None] if img.ndim == 2 else img
    w, h = frame.image_size
    if img.shape[:2] != (h, w) or img.ndim != 3:
        raise AppearanceError(f"frame {frame.name!r}: image of shape {img.shape}; expected ({h}, {w}, C)")
    return img


def _lamp_dirs(frame: FramePose, points: NDArray[np.float64]) -> NDArray[np.float64]:
    out = np.empty((len(points), len(frame.lamps), 3))
    for j, lamp in enumerate(frame.lamps):
        if lamp.kind == "distant":
            out[:, j] = lamp.vector
        else:
            d = lamp.vector - points
            out[:, j] = d / np.linalg.norm(d, axis=1, keepdims=True)
    return out


def _frame_rows(k: int, frame: FramePose, img: NDArray[np.float32], idx: NDArray[np.intp],
                v: NDArray[np.float64], n: NDArray[np.float64], noise_ab: NDArray[np.float64],
                clip_level: float) -> dict[str, NDArray[Any]]:
    """One frame's observation rows for the visible vertices ``idx``."""
    uv = project_points(v[idx], frame)[0]
    signal = bilinear(img, uv)
    sigma = np.sqrt(np.maximum(noise_ab[0] + noise_ab[1] * signal, 0.0)).astype(np.float32)
    # channel maximum by slices (a reduction over a short last axis is slow), then the 3 x 3 maximum
    peak = cv2.dilate(functools.reduce(np.maximum, [img[..., c] for c in range(img.shape[2])]),
                      np.ones((3, 3), np.uint8))
    h, w = img.shape[:2]
    col = np.clip(np.rint(uv[:, 0]), 0, w - 1).astype(np.intp)
    row = np.clip(np.rint(uv[:, 1]), 0, h - 1).astype(np.intp)
    if not (np.all(np.isfinite(signal)) and np.all(np.isfinite(peak[row, col]))):
        raise AppearanceError(f"frame {frame.name!r}: image has NaN or infinite pixels where the mesh is seen; "
                              "give a finite linear image")
    to_cam = frame.camera_centre_mm - v[idx]
    dist = np.linalg.norm(to_cam, axis=1)
    view = to_cam / dist[:, None]
    light = _lamp_dirs(frame, v[idx])
    half = light + view[:, None, :]
    half /= np.maximum(np.linalg.norm(half, axis=2, keepdims=True), 1e-12)
    cos_h = np.clip(np.einsum("nlc,nc->nl", half, n[idx]), -1.0, 1.0)
    return {"vertex": idx.astype(np.int32), "frame": np.full(len(idx), k, dtype=np.int32),
            "uv_px": uv.astype(np.float32), "signal": signal, "sigma": sigma, "clipped": peak[row, col] >= clip_level,
            "normal": n[idx].astype(np.float32), "view_dir": view.astype(np.float32),
            "light_dir": light.astype(np.float32), "half_angle_deg": np.degrees(np.arccos(cos_h)).astype(np.float32),
            "distance_mm": dist.astype(np.float32)}


def _per_frame(value: Any, count: int, shape: tuple[int, ...], what: str) -> NDArray[np.float64]:
    a = np.asarray(value, dtype=np.float64)
    if a.shape == shape:
        a = np.broadcast_to(a, (count, *shape))
    if a.shape != (count, *shape) or not np.all(np.isfinite(a)):
        raise AppearanceError(f"{what}: give finite values of shape {shape} or ({count}, *{shape}) per frame")
    return a


def observe(frames: Sequence[FramePose], mesh: Any, images: Sequence[Any], *, noise: ArrayLike,
            clip_level: ArrayLike, max_view_deg: float = 75.0, edge_margin_px: float = 2.0,
            depth_binning: int = 2, occlusion_tol_rel: float = 1e-3) -> Observations:
    """Sample every frame at the vertices it sees and record the geometry.

    Parameters
    ----------
    frames
        The frames' poses (all with the same lamps, in the same order).
    mesh
        Open3D ``TriangleMesh`` or ``(vertices, triangles[, normals])`` in M; its
        vertex normals (outward) are used when present, else computed by Open3D.
    images
        ``images[k]``: float ``(H, W, C)`` linear, chart-calibrated image of
        ``frames[k]`` (read one at a time, so a lazy sequence keeps memory low).
    noise
        ``(2,)`` or ``(K, 2)``: ``(a, b)`` of ``sigma^2 = a + b * signal`` per frame.
    clip_level
        Scalar or ``(K,)``: the signal at which a frame clips.
    max_view_deg, edge_margin_px, depth_binning, occlusion_tol_rel
        As :func:`~processing.appearance.visibility.visible_vertices`.

    Returns
    -------
    Observations
        Sorted by vertex.
    """
    frames = list(frames)
    if not frames or len(images) != len(frames):
        raise AppearanceError(f"observe: {len(frames)} frames and {len(images)} images; give one image per frame")
    lamp_names = tuple(lp.name for lp in frames[0].lamps)
    for f in frames:
        if tuple(lp.name for lp in f.lamps) != lamp_names:
            raise AppearanceError(f"frame {f.name!r}: lamps {[lp.name for lp in f.lamps]}; every frame needs "
                                  f"the same lamps {list(lamp_names)}")
    noise_ab = _per_frame(noise, len(frames), (2,), "noise")
    clips = _per_frame(clip_level, len(frames), (), "clip_level")
    v, f_idx, n = mesh_arrays(mesh)
    scene = raycasting_scene(v, f_idx)
    rows = []
    for k, frame in enumerate(frames):
        img = _check_image(images[k], frame)
        seen = visible_vertices(v, f_idx, n, frame, max_view_deg=max_view_deg, edge_margin_px=edge_margin_px,
                                depth_binning=depth_binning, occlusion_tol_rel=occlusion_tol_rel, scene=scene)
        rows.append(_frame_rows(k, frame, img, np.flatnonzero(seen), v, n, noise_ab[k], float(clips[k])))
    return _assemble(rows, len(v), tuple(f.name for f in frames), lamp_names)


def _assemble(rows: list[dict[str, NDArray[Any]]], n_vertices: int, frame_names: tuple[str, ...],
              lamp_names: tuple[str, ...]) -> Observations:
    cat = {name: np.concatenate([r[name] for r in rows]) for name in _ROW_ARRAYS}
    order = np.argsort(cat["vertex"], kind="stable")
    cat = {name: np.ascontiguousarray(a[order]) for name, a in cat.items()}
    offsets = np.zeros(n_vertices + 1, dtype=np.int64)
    np.cumsum(np.bincount(cat["vertex"], minlength=n_vertices), out=offsets[1:])
    return Observations(n_vertices, frame_names, lamp_names, offsets, **cat)


def write_observations(path: str | os.PathLike[str], obs: Observations) -> None:
    """Write observations to an ``.npz`` (no pickles; schema and version keys).

    Parameters
    ----------
    path
        Destination file (``.npz``).
    obs
        The observations.
    """
    arrays = {name: getattr(obs, name) for name in ("offsets", *_ROW_ARRAYS)}
    with open(path, "wb") as fh:
        np.savez(fh, schema=np.array(OBSERVATIONS_SCHEMA), version=np.array(OBSERVATIONS_VERSION, dtype=np.int64),
                 n_vertices=np.array(obs.n_vertices, dtype=np.int64),
                 frame_names=np.array(obs.frame_names, dtype=str).reshape(-1),
                 lamp_names=np.array(obs.lamp_names, dtype=str).reshape(-1), **arrays)


#: name -> (dtype, trailing shape; "C" = channels, "L" = lamps)
_SPEC: dict[str, tuple[type, tuple[Any, ...]]] = {
    "vertex": (np.int32, ()), "frame": (np.int32, ()), "uv_px": (np.float32, (2,)), "signal": (np.float32, ("C",)),
    "sigma": (np.float32, ("C",)), "clipped": (np.bool_, ()), "normal": (np.float32, (3,)),
    "view_dir": (np.float32, (3,)), "light_dir": (np.float32, ("L", 3)), "half_angle_deg": (np.float32, ("L",)),
    "distance_mm": (np.float32, ()),
}


def _load(path: str | os.PathLike[str]) -> dict[str, NDArray[Any]]:
    """Every array of an untrusted observations ``.npz``, each checked against its member before it is allocated."""
    return read_npz(path, what="an observations file", error=AppearanceError,
                    remedy="write it with write_observations")


def _scalar(data: dict[str, NDArray[Any]], key: str, where: str) -> Any:
    a = data.get(key)
    if a is None or a.shape != () or a.dtype.hasobject:
        raise AppearanceError(f"{where}: {key!r} missing or not a scalar; not an observations file")
    return a.item()


def _check_array(where: str, name: str, a: NDArray[Any] | None, n: int, dims: dict[str, int]) -> None:
    dtype, trailing = _SPEC[name]
    if a is None:
        raise AppearanceError(f"{where}: array {name!r} missing; rewrite it with write_observations")
    shape = (n, *(dims[t] if isinstance(t, str) else t for t in trailing))
    if a.dtype != np.dtype(dtype) or a.shape != shape:
        raise AppearanceError(f"{where}: array {name!r} is {a.dtype} {a.shape}, expected {np.dtype(dtype)} {shape}")
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise AppearanceError(f"{where}: array {name!r} has NaN or infinite values")


def _check_bounds(where: str, d: dict[str, NDArray[Any]], n_vertices: int, n_frames: int) -> None:
    def bad(name: str, ok: bool, what: str) -> None:
        if not ok:
            raise AppearanceError(f"{where}: array {name!r} {what}")

    off = d["offsets"]
    bad("offsets", off.dtype == np.int64 and off.shape == (n_vertices + 1,), f"is {off.dtype} {off.shape}, "
        f"expected int64 ({n_vertices + 1},)")
    bad("offsets", off[0] == 0 and off[-1] == len(d["vertex"]) and bool(np.all(np.diff(off) >= 0)),
        "is not non-decreasing from 0 to the number of observations")
    bad("vertex", bool(np.all((d["vertex"] >= 0) & (d["vertex"] < n_vertices))), f"has indices outside 0..{n_vertices - 1}")
    bad("vertex", bool(np.array_equal(np.bincount(d["vertex"], minlength=n_vertices), np.diff(off))),
        "does not match the offsets (not sorted by vertex)")
    bad("frame", bool(np.all((d["frame"] >= 0) & (d["frame"] < n_frames))), f"has indices outside 0..{n_frames - 1}")
    bad("sigma", bool(np.all(d["sigma"] >= 0)), "has negative values")
    bad("distance_mm", bool(np.all(d["distance_mm"] > 0)), "has non-positive values")
    bad("half_angle_deg", bool(np.all((d["half_angle_deg"] >= 0) & (d["half_angle_deg"] <= 180))), "is outside 0..180")
    for name in ("normal", "view_dir", "light_dir"):
        bad(name, bool(np.all(np.abs(np.linalg.norm(d[name], axis=-1) - 1.0) < 1e-3)), "has non-unit vectors")


def read_observations(path: str | os.PathLike[str]) -> Observations:
    """Read and check an observations ``.npz`` (untrusted: every array is checked).

    Parameters
    ----------
    path
        The file.

    Returns
    -------
    Observations

    Raises
    ------
    AppearanceError
        One line naming the file and the array when anything is wrong.
    """
    where = os.fspath(path)
    d = _load(path)
    if _scalar(d, "schema", where) != OBSERVATIONS_SCHEMA or _scalar(d, "version", where) != OBSERVATIONS_VERSION:
        raise AppearanceError(f"{where}: schema/version {d['schema'].item()!r}/{d['version'].item()!r}; expected "
                              f"{OBSERVATIONS_SCHEMA!r}/{OBSERVATIONS_VERSION}")
    n_vertices = _scalar(d, "n_vertices", where)
    if not isinstance(n_vertices, int) or not 0 < n_vertices < 2**31:
        raise AppearanceError(f"{where}: 'n_vertices' is {n_vertices!r}; expected a positive count")
    names = {}
    for key in ("frame_names", "lamp_names"):
        a = d.get(key)
        if a is None or a.ndim != 1 or a.dtype.kind != "U":
            raise AppearanceError(f"{where}: array {key!r} missing or not a 1-D array of strings")
        names[key] = tuple(str(x) for x in a)
    if "vertex" not in d or d["vertex"].ndim != 1 or "signal" not in d or d["signal"].ndim != 2:
        raise AppearanceError(f"{where}: array 'vertex' or 'signal' missing or of the wrong rank")
    dims = {"C": d["signal"].shape[1], "L": len(names["lamp_names"])}
    for name in _SPEC:
        _check_array(where, name, d.get(name), len(d["vertex"]), dims)
    if "offsets" not in d:
        raise AppearanceError(f"{where}: array 'offsets' missing; rewrite it with write_observations")
    _check_bounds(where, d, n_vertices, len(names["frame_names"]))
    kw = {f.name: d[f.name] for f in fields(Observations) if f.name in _SPEC or f.name == "offsets"}
    return Observations(n_vertices, names["frame_names"], names["lamp_names"], **kw)
