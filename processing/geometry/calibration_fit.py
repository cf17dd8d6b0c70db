"""Building blocks of the sphere calibration: table line, sphere sections, circles, closed-form start, fit.

Used by :func:`processing.geometry.calibration.calibrate_sphere`; the
method is described in docs/processing.md, section "Calibration fit".
Profiles are (S, P) arrays of sensor coordinates ``(x, z)`` in mm, angles in
radians.

References
----------
.. [1] Kasa, I. (1976). A circle fitting procedure and its error analysis.
   IEEE Trans. Instrum. Meas. 25(1), 8-14.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from processing.common.rotation import rotation_z

__all__: list[str] = []


# ---------------------------------------------------------------------------- segmentation
def _fit_table_line(x: NDArray, z: NDArray, valid: NDArray, tol: float
                    ) -> tuple[NDArray[np.bool_], NDArray[np.float64] | None]:
    """RANSAC line common to all profiles; returns the inlier mask and (nx, nz, c) with nx x + nz z = c."""
    s = x.shape[0]
    rows = np.broadcast_to(np.arange(s)[:, None], x.shape)[valid]
    px, pz = x[valid], z[valid]
    none = np.zeros_like(valid)
    if px.size < 20:
        return none, None
    rng = np.random.default_rng(12345)
    sub = rng.choice(px.size, size=min(px.size, 4000), replace=False)
    sx, sz = px[sub], pz[sub]
    i, j = rng.integers(0, sub.size, (2, 256))
    dx, dz = sx[j] - sx[i], sz[j] - sz[i]
    ln = np.hypot(dx, dz)
    good = ln > 1.0
    if not good.any():
        return none, None
    nx, nz = -dz[good] / ln[good], dx[good] / ln[good]
    c = nx * sx[i][good] + nz * sz[i][good]
    count = (np.abs(np.outer(nx, sx) + np.outer(nz, sz) - c[:, None]) < tol).sum(1)
    k = int(np.argmax(count))
    line = np.array([nx[k], nz[k], c[k]])
    inl = np.abs(line[0] * px + line[1] * pz - line[2]) < tol
    for _ in range(3):  # total least squares on the inliers, then reselect
        if inl.sum() < 3:
            return none, None
        q = np.stack([px[inl], pz[inl]], 1)
        mu = q.mean(0)
        _, _, vt = np.linalg.svd(q - mu, full_matrices=False)
        n = vt[1]
        line = np.array([n[0], n[1], n @ mu])
        inl = np.abs(line[0] * px + line[1] * pz - line[2]) < tol
    per_row = np.bincount(rows[inl], minlength=s)
    if (per_row >= 5).sum() < max(3, 0.3 * s):
        return none, None
    mask = np.zeros_like(valid)
    mask[valid] = inl
    return mask, line


def _longest_runs(x: NDArray, z: NDArray, mask: NDArray, gap_mm: float) -> NDArray[np.bool_]:
    """Per profile, the longest run of consecutive valid points no farther than ``gap_mm`` apart."""
    s, p = x.shape
    idx = np.where(mask, np.arange(p), -1)
    prev = np.maximum.accumulate(idx, axis=1)
    prev = np.concatenate([np.full((s, 1), -1), prev[:, :-1]], axis=1)
    has = prev >= 0
    pc = np.clip(prev, 0, None)
    with np.errstate(invalid="ignore"):
        dist = np.hypot(x - np.take_along_axis(x, pc, 1), z - np.take_along_axis(z, pc, 1))
    brk = mask & (~has | ~(dist <= gap_mm))
    seg = np.cumsum(brk.ravel()).reshape(s, p) - 1
    if not brk.any():
        return np.zeros_like(mask)
    counts = np.bincount(seg[mask], minlength=int(brk.sum()))
    seg_row = np.nonzero(brk)[0]
    order = np.lexsort((-counts, seg_row))
    _, first = np.unique(seg_row[order], return_index=True)
    best = np.zeros(counts.size, dtype=bool)
    best[order[first]] = True
    return mask & best[np.where(mask, seg, 0)]


def _fit_circles(x: NDArray, z: NDArray, mask: NDArray, floor_mm: float, rounds: int = 3
                 ) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Circle per profile (Kasa start, Gauss-Newton, trimming), vectorised; returns cx, cz, r, rms, n, mask."""
    s = x.shape[0]
    m = mask.copy()
    cx = np.zeros(s)
    cz = np.zeros(s)
    r = np.zeros(s)
    rms = np.full(s, np.inf)
    for rnd in range(rounds):
        w = m.astype(np.float64)
        n = w.sum(1)
        ok = n >= 5
        nn = np.where(ok, n, 1.0)
        mx = np.where(m, x, 0.0).sum(1) / nn
        mz = np.where(m, z, 0.0).sum(1) / nn
        X = np.where(m, x - mx[:, None], 0.0)
        Z = np.where(m, z - mz[:, None], 0.0)
        if rnd == 0:
            a = np.stack([X, Z, w], -1)                                   # (S, P, 3)
            b = -(X * X + Z * Z)
            ata = np.einsum("spi,spj->sij", a, a)
            atb = np.einsum("spi,sp->si", a, b)
            ata[~ok] = np.eye(3)
            atb[~ok] = 0.0
            sol = np.linalg.solve(ata, atb[..., None])[..., 0]
            ccx, ccz = -sol[:, 0] / 2, -sol[:, 1] / 2
            r = np.sqrt(np.clip(ccx * ccx + ccz * ccz - sol[:, 2], 0.0, None))
        else:
            ccx, ccz = cx - mx, cz - mz
        for _ in range(6):
            ex, ez = X - ccx[:, None], Z - ccz[:, None]
            rho = np.hypot(ex, ez)
            rho_s = np.where(rho > 1e-12, rho, 1.0)
            res = np.where(m, rho - r[:, None], 0.0)
            jac = np.stack([-ex / rho_s, -ez / rho_s, -np.ones_like(ex)], -1) * w[..., None]
            jtj = np.einsum("spi,spj->sij", jac, jac)
            jtr = np.einsum("spi,sp->si", jac, res)
            jtj[~ok] = np.eye(3)
            jtr[~ok] = 0.0
            jtj += 1e-12 * np.eye(3)
            step = np.linalg.solve(jtj, -jtr[..., None])[..., 0]
            ccx, ccz, r = ccx + step[:, 0], ccz + step[:, 1], r + step[:, 2]
        cx, cz = ccx + mx, ccz + mz
        dist = np.abs(np.hypot(x - cx[:, None], z - cz[:, None]) - r[:, None])
        dist = np.where(m, dist, 0.0)
        rms = np.where(ok, np.sqrt((dist * dist).sum(1) / nn), np.inf)
        if rnd < rounds - 1:
            lim = np.maximum(3.0 * rms, floor_mm)
            m = m & (dist <= lim[:, None])
    n = m.sum(1)
    return cx, cz, np.abs(r), rms, n, m


# ---------------------------------------------------------------------------- closed-form start
def _initial_pose(a: NDArray, cu: NDArray, cv: NDArray, r: NDArray, w: NDArray, radius: float,
                  table_pts: NDArray | None, sphere_height: float | None
                  ) -> tuple[NDArray, NDArray, float, float]:
    """Sensor-to-room rotation, origin, trajectory radius rho and centre height h (gauge phi = 0)."""
    basis = np.stack([np.cos(a), np.sin(a), np.ones_like(a)], 1)
    sw = np.sqrt(w)[:, None]
    ku = np.linalg.lstsq(basis * sw, cu * sw[:, 0], rcond=None)[0]
    kv = np.linalg.lstsq(basis * sw, cv * sw[:, 0], rcond=None)[0]
    va, vb = np.array([ku[0], kv[0]]), np.array([ku[1], kv[1]])
    root = np.sqrt(complex(vb @ vb - va @ va, -2.0 * (va @ vb)))
    e = radius * radius - r * r
    candidates = []
    for sign in (1.0, -1.0):
        y1, y2 = sign * root.real, sign * root.imag
        g = y1 * np.cos(a) + y2 * np.sin(a)
        q = g * g - e
        cub = [a.size, 3.0 * g.sum(), 2.0 * (g * g).sum() + q.sum(), (q * g).sum()]
        roots = np.roots(cub)
        roots = roots[np.abs(roots.imag) < 1e-6 * (1.0 + np.abs(roots.real))].real
        cost = [float((((g + c0) ** 2 - e) ** 2).sum()) for c0 in roots]
        cd = float(roots[int(np.argmin(cost))])
        f1 = np.array([ku[0], y1, kv[0]])
        f2 = np.array([ku[1], y2, kv[1]])
        k3 = np.array([ku[2], cd, kv[2]])
        rho = math.sqrt(0.5 * (f1 @ f1 + f2 @ f2))
        mm = np.stack([f1, f2, np.cross(f1, f2) / max(rho * rho, 1e-12)], 1)
        u, _, vt = np.linalg.svd(mm)
        rot_t = u @ vt
        if np.linalg.det(rot_t) < 0:
            u[:, -1] *= -1
            rot_t = u @ vt
        rot = rot_t.T                               # sensor -> room
        e3 = rot_t[:, 2]                            # room +Z in sensor coordinates
        rk = rot @ k3
        if table_pts is not None:
            oz = -float(np.mean(table_pts @ e3))
            h = oz + rk[2] if sphere_height is None else sphere_height
            up = oz > 0
        else:
            h = float(sphere_height)                # checked by the caller
            up = rot[2, 0] > 0
        o = np.array([0.0, 0.0, h]) - rk
        candidates.append((up, rot, o, rho, h))
    # the two candidates are mirror images: exactly one has "up" the right way
    _, rot, o, rho, h = next((c for c in candidates if c[0]), candidates[0])
    return rot, o, rho, h


# ---------------------------------------------------------------------------- refinement
def _refine(rot0: NDArray, o0: NDArray, rho0: float, h0: float, radius: float, free_radius: bool,
            fix_h: bool, sp: NDArray, sa: NDArray, tp: NDArray | None, f_scale: float
            ) -> tuple[NDArray, NDArray, float, float, float, Any]:
    """Least squares over (rotation vector, origin, rho, [h], [R]); sp (N,2) sensor (x, z), sa (N,) angles."""
    ca, sn = np.cos(sa), np.sin(sa)

    def unpack(p: NDArray) -> tuple[NDArray, NDArray, float, float, float]:
        rot = Rotation.from_rotvec(p[:3]).as_matrix() @ rot0
        o = p[3:6]
        rho = p[6]
        k = 7
        h = h0
        if not fix_h:
            h = p[k]
            k += 1
        rr = p[k] if free_radius else radius
        return rot, o, rho, h, rr

    def fun(p: NDArray) -> NDArray:
        rot, o, rho, h, rr = unpack(p)
        pts = sp[:, :1] * rot[:, 0] + sp[:, 1:] * rot[:, 2] + o
        d = np.sqrt((pts[:, 0] - rho * ca) ** 2 + (pts[:, 1] - rho * sn) ** 2 + (pts[:, 2] - h) ** 2) - rr
        if tp is None:
            return d
        tz = tp[:, 0] * rot[2, 0] + tp[:, 1] * rot[2, 2] + o[2]
        return np.concatenate([d, tz])

    p0 = [0.0, 0.0, 0.0, *o0, rho0]
    if not fix_h:
        p0.append(h0)
    if free_radius:
        p0.append(radius)
    res = least_squares(fun, np.array(p0), method="trf", loss="soft_l1", f_scale=f_scale, x_scale="jac",
                        xtol=1e-12, ftol=1e-12, gtol=1e-10, max_nfev=200)
    rot, o, rho, h, rr = unpack(res.x)
    return rot, o, float(rho), float(h), float(rr), res


def _table_sample(x: NDArray, z: NDArray, mask: NDArray, most: int = 4000) -> NDArray[np.float64]:
    """(M, 2) sensor (x, z) of table points, an even subsample of at most ``most``.

    The table fixes only the height and tilt of the frame; more points cost
    time, not accuracy.
    """
    pts = np.stack([x[mask], z[mask]], 1)
    step = max(1, -(-len(pts) // most))
    return pts[::step]


def _sphere_distance(x: NDArray, z: NDArray, a: NDArray, rot: NDArray, o: NDArray, centre: NDArray) -> NDArray:
    """Distance of every profile point (S, P) from the sphere centre at each step's angle."""
    pts = x[..., None] * rot[:, 0] + z[..., None] * rot[:, 2] + o
    c = np.einsum("sij,j->si", rotation_z(a), centre)
    return np.linalg.norm(pts - c[:, None, :], axis=-1)
