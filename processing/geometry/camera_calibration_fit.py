"""Building blocks of the turntable camera calibration: the model, its start and the joint fit.

The model of a board corner ``X`` seen in view ``v`` (table angle ``theta_v``,
board placement ``g``) is ``x_cam = A Rz(theta_v) B_g X`` followed by OpenCV's
pinhole projection with distortion ``(k1, k2, p1, p2, k3)``.  ``A`` maps the
*gauge table frame* (turntable axis = +z through the origin) to the camera;
the board cannot see a rotation about the axis or a shift along it, so the
gauge puts the camera centre at ``(0, -rho, 0)``: ``A`` has 4 free parameters
(its rotation vector and ``rho``).  The parameter vector is
``[fx, fy, cx, cy, k1, k2, p1, p2, (k3), rA(3), rho, (rB_g(3), tB_g(3)) per group]``.

References
----------
.. [1] Zhang, Z. (2000). A flexible new technique for camera calibration.
   IEEE TPAMI 22(11), 1330-1334. doi:10.1109/34.888718
.. [2] Kasa, I. (1976). A circle fitting procedure and its error analysis.
   IEEE Trans. Instrum. Meas. 25(1), 8-14. doi:10.1109/TIM.1976.6312298
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from processing.common.rotation import rotation_z

__all__ = [
    "FitProblem",
    "angle_span_deg",
    "axis_from_poses",
    "covariance",
    "gauge_transform",
    "initial_state",
    "per_view_rms",
    "project_model",
    "solve",
    "start_intrinsics",
]


@dataclass
class FitProblem:
    """Stacked observations of the joint fit.

    Attributes
    ----------
    obj_mm
        ``(M, 3)`` board-frame corners of every observation.
    img_px
        ``(M, 2)`` measured pixels.
    view
        ``(M,)`` view index of each observation.
    angle_rad
        ``(V,)`` table angle of each view.
    group
        ``(V,)`` group index of each view.
    n_groups
        Number of groups.
    fit_k3
        Whether k3 is a free parameter.
    fixed
        Indices of parameters held at their start values (e.g. the tangential
        distortion ``(6, 7)``, which a long lens cannot separate from the pose).
    """

    obj_mm: NDArray[np.float64]
    img_px: NDArray[np.float64]
    view: NDArray[np.int64]
    angle_rad: NDArray[np.float64]
    group: NDArray[np.int64]
    n_groups: int
    fit_k3: bool = False
    fixed: tuple[int, ...] = ()

    @property
    def n_intr(self) -> int:
        """Number of intrinsic parameters.

        Returns
        -------
        int
        """
        return 9 if self.fit_k3 else 8


def gauge_transform(rot_vec: NDArray[np.float64], rho_mm: float) -> NDArray[np.float64]:
    """``A`` (4x4, gauge table frame -> camera) from its rotation vector and the camera's axis distance.

    Parameters
    ----------
    rot_vec
        Rotation vector of ``A``'s rotation, ``(3,)``.
    rho_mm
        Distance of the camera centre from the axis (mm); the centre is at ``(0, -rho, 0)``.

    Returns
    -------
    ndarray
        ``(4, 4)``.
    """
    r = Rotation.from_rotvec(rot_vec).as_matrix()
    out = np.eye(4)
    out[:3, :3] = r
    out[:3, 3] = rho_mm * r[:, 1]
    return out


def _split(p: NDArray[np.float64], prob: FitProblem) -> tuple:
    """Intrinsics, distortion, A and the groups' (R, t) from a parameter vector."""
    n = prob.n_intr
    fx, fy, cx, cy = p[:4]
    dist = np.zeros(5)
    dist[:4] = p[4:8]
    if prob.fit_k3:
        dist[4] = p[8]
    a = gauge_transform(p[n:n + 3], p[n + 3])
    gp = p[n + 4:].reshape(prob.n_groups, 6)
    rb = Rotation.from_rotvec(gp[:, :3]).as_matrix()
    return (fx, fy, cx, cy), dist, a, rb, gp[:, 3:]


def project_model(p: NDArray[np.float64], prob: FitProblem) -> NDArray[np.float64]:
    """Model pixels ``(M, 2)`` of every observation.

    Parameters
    ----------
    p
        Parameter vector (module notes).
    prob
        The stacked observations.

    Returns
    -------
    ndarray
        ``(M, 2)``.
    """
    (fx, fy, cx, cy), dist, a, rb, tb = _split(p, prob)
    rz = rotation_z(prob.angle_rad)
    rv = a[:3, :3] @ rz @ rb[prob.group]
    tv = (a[:3, :3] @ rz @ tb[prob.group][..., None])[..., 0] + a[:3, 3]
    xc = np.einsum("mij,mj->mi", rv[prob.view], prob.obj_mm) + tv[prob.view]
    z = np.where(np.abs(xc[:, 2]) > 1e-9, xc[:, 2], 1e-9)
    x, y = xc[:, 0] / z, xc[:, 1] / z
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([fx * xd + cx, fy * yd + cy], axis=1)


def axis_from_poses(rots: NDArray[np.float64], angles_rad: NDArray[np.float64],
                    groups: NDArray[np.int64]) -> NDArray[np.float64] | None:
    """The turntable axis in the camera frame from the relative rotations of the views of each group.

    Parameters
    ----------
    rots
        ``(V, 3, 3)`` board -> camera rotations.
    angles_rad
        ``(V,)`` table angles.
    groups
        ``(V,)`` group of each view.

    Returns
    -------
    ndarray or None
        Unit ``(3,)`` (right-handed with the table angle), or None without usable pairs.
    """
    i, j = np.triu_indices(len(rots), 1)
    keep = groups[i] == groups[j]
    i, j = i[keep], j[keep]
    d = np.angle(np.exp(1j * (angles_rad[j] - angles_rad[i])))
    w = np.sin(np.abs(d))
    ok = w > 0.2
    if not ok.any():
        return None
    rel = np.einsum("nij,nkj->nik", rots[j[ok]], rots[i[ok]])
    rv = Rotation.from_matrix(rel).as_rotvec()
    unit = rv / np.maximum(np.linalg.norm(rv, axis=1, keepdims=True), 1e-12)
    s = (unit * (np.sign(d[ok]) * w[ok])[:, None]).sum(axis=0)
    return s / np.linalg.norm(s) if np.linalg.norm(s) > 0 else None


def _kasa(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Centre of the circle through 2-D points (algebraic fit [2])."""
    m = np.column_stack([q, np.ones(len(q))])
    sol = np.linalg.lstsq(m, (q ** 2).sum(axis=1), rcond=None)[0]
    return 0.5 * sol[:2]


def initial_state(rots: NDArray[np.float64], trans: NDArray[np.float64], prob: FitProblem,
                  axis_groups: list[int]) -> tuple[NDArray[np.float64], float, NDArray[np.float64]] | None:
    """``A`` (rotation vector, rho) and the groups' poses from per-view board poses.

    Parameters
    ----------
    rots, trans
        ``(V, 3, 3)``, ``(V, 3)`` board -> camera poses of the views (e.g. from ``cv2.calibrateCamera``).
    prob
        The stacked observations (angles and groups are used).
    axis_groups
        Groups whose views span enough table angles to show the axis.

    Returns
    -------
    tuple or None
        ``(rA (3,), rho, group parameters (G, 6))``; None when the axis cannot be found.
    """
    use = np.isin(prob.group, axis_groups)
    axis = axis_from_poses(rots[use], prob.angle_rad[use], prob.group[use])
    if axis is None:
        return None
    e1 = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    centres, weights = [], []
    for g in axis_groups:
        o = trans[prob.group == g]
        c2 = _kasa(np.column_stack([o @ e1, o @ e2]))
        centres.append(c2[0] * e1 + c2[1] * e2 + (o @ axis).mean() * axis)
        weights.append(len(o))
    p = np.average(np.array(centres), axis=0, weights=weights)
    d_perp = -p - (-p @ axis) * axis
    rho = float(np.linalg.norm(d_perp))
    y_t = -d_perp / rho
    r_a = np.column_stack([np.cross(y_t, axis), y_t, axis])
    a = gauge_transform(Rotation.from_matrix(r_a).as_rotvec(), rho)
    return Rotation.from_matrix(r_a).as_rotvec(), rho, _group_poses(a, rots, trans, prob)


def _group_poses(a: NDArray[np.float64], rots: NDArray[np.float64], trans: NDArray[np.float64],
                 prob: FitProblem) -> NDArray[np.float64]:
    """Each group's board -> table pose: the medoid of its views' ``Rz(-theta) A^-1 T_v``."""
    inv_a = np.linalg.inv(a)
    out = np.zeros((prob.n_groups, 6))
    for g in range(prob.n_groups):
        idx = np.flatnonzero(prob.group == g)
        rz = rotation_z(-prob.angle_rad[idx])
        rb = rz @ inv_a[:3, :3] @ rots[idx]
        tb = (rz @ (inv_a[:3, :3] @ trans[idx].T + inv_a[:3, 3:]).T[..., None])[..., 0]
        rel = np.einsum("aij,bkj->abik", rb, rb)
        ang = np.arccos(np.clip((np.trace(rel, axis1=2, axis2=3) - 1) / 2, -1, 1))
        cost = np.degrees(ang).sum(axis=1) + np.linalg.norm(tb[:, None] - tb[None], axis=2).sum(axis=1) / 10.0
        k = int(np.argmin(cost))
        out[g, :3] = Rotation.from_matrix(rb[k]).as_rotvec()
        out[g, 3:] = tb[k]
    return out


def solve(p0: NDArray[np.float64], prob: FitProblem, loss: str = "linear") -> object:
    """Joint least squares of all parameters on the corner reprojection errors.

    Parameters
    ----------
    p0
        Start parameter vector.
    prob
        The stacked observations.
    loss
        ``scipy.optimize.least_squares`` loss (``"linear"`` or a robust one, scale 1 px).

    Returns
    -------
    scipy.optimize.OptimizeResult
    """
    free = np.ones(len(p0), dtype=bool)
    free[list(prob.fixed)] = False

    def fun(q: NDArray[np.float64]) -> NDArray[np.float64]:
        p = p0.copy()
        p[free] = q
        return (project_model(p, prob) - prob.img_px).ravel()

    res = least_squares(fun, p0[free], method="trf", loss=loss, f_scale=1.0, x_scale="jac", max_nfev=200)
    x = p0.copy()
    x[free] = res.x
    jac = np.zeros((res.jac.shape[0], len(p0)))
    jac[:, free] = res.jac
    res.x, res.jac = x, jac
    return res


def per_view_rms(p: NDArray[np.float64], prob: FitProblem) -> NDArray[np.float64]:
    """RMS reprojection error (px) of each view.

    Parameters
    ----------
    p
        Parameter vector.
    prob
        The stacked observations.

    Returns
    -------
    ndarray
        ``(V,)``.
    """
    e2 = ((project_model(p, prob) - prob.img_px) ** 2).sum(axis=1)
    n = np.bincount(prob.view, minlength=len(prob.angle_rad))
    return np.sqrt(np.bincount(prob.view, e2, minlength=len(prob.angle_rad)) / np.maximum(n, 1))


def start_intrinsics(objs: list, imgs: list, image_size: tuple[int, int], initial_focal_px: float | None,
                     fit_k3: bool) -> tuple:
    """Intrinsics and per-view poses: ``cv2.calibrateCamera``, or a given focal and ``solvePnP``.

    Parameters
    ----------
    objs, imgs
        Per-view board corners (mm, ``(N, 3)``) and pixels (``(N, 2)``).
    image_size
        ``(width, height)``.
    initial_focal_px
        Focal length to start from (no ``calibrateCamera``), or None.
    fit_k3
        Let ``calibrateCamera`` fit k3.

    Returns
    -------
    tuple
        ``(K, dist (5,), rots (V, 3, 3), trans (V, 3))``.
    """
    w, h = image_size
    o32 = [np.asarray(o, np.float32) for o in objs]
    i32 = [np.asarray(i, np.float32).reshape(-1, 1, 2) for i in imgs]
    if initial_focal_px is None:
        flags = 0 if fit_k3 else cv2.CALIB_FIX_K3
        _, k, dist, rvecs, tvecs = cv2.calibrateCamera(o32, i32, (w, h), None, None, flags=flags)
    else:
        f = float(initial_focal_px)
        k = np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1.0]])
        dist = np.zeros(5)
        rvecs, tvecs = [], []
        for o, i in zip(o32, i32):
            _, rv, tv = cv2.solvePnP(o, i, k, dist, flags=cv2.SOLVEPNP_IPPE)
            _, rv, tv = cv2.solvePnP(o, i, k, dist, rv, tv, True, flags=cv2.SOLVEPNP_ITERATIVE)
            rvecs.append(rv)
            tvecs.append(tv)
    rots = Rotation.from_rotvec(np.array([np.ravel(r) for r in rvecs])).as_matrix()
    trans = np.array([np.ravel(t) for t in tvecs], dtype=np.float64)
    d5 = np.zeros(5)
    d5[:min(5, np.size(dist))] = np.ravel(dist)[:5]
    return np.asarray(k, np.float64), d5, rots, trans


def angle_span_deg(angles_deg: NDArray[np.float64]) -> float:
    """Smallest arc (deg) holding all the angles: 360 minus the largest gap between them.

    Parameters
    ----------
    angles_deg
        Table angles.

    Returns
    -------
    float
    """
    a = np.sort(np.unique(np.round(np.mod(angles_deg, 360.0), 6)))
    if a.size < 2:
        return 0.0
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    return float(360.0 - gaps.max())


def covariance(res: object, n_resid: int) -> NDArray[np.float64]:
    """Parameter covariance ``s^2 (J^T J)^-1`` at the solution, ``s^2`` the residual variance.

    Parameters
    ----------
    res
        ``least_squares`` result (linear loss).
    n_resid
        Number of residuals.

    Returns
    -------
    ndarray
        ``(P, P)``.
    """
    jac = res.jac
    dof = max(n_resid - int(np.count_nonzero(np.any(jac != 0, axis=0))), 1)
    s2 = 2.0 * float(res.cost) / dof
    return np.linalg.pinv(jac.T @ jac) * s2

