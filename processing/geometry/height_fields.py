"""Smooth height fields fitted to the data around a hole: sphere plus spline, spline, plane, floor.

Used by :mod:`processing.geometry.holes`; a height field ``h(u, v)`` is
defined over a hole's local frame (``u, v`` across the hole's direction, ``h``
along it, mm).  See docs/processing.md, section "Hole filling".

References
----------
.. [1] Pratt, V. (1987). Direct least-squares fitting of algebraic surfaces.
   SIGGRAPH 1987. doi:10.1145/37402.37420
.. [2] Duchon, J. (1977). Splines minimizing rotation-invariant semi-norms
   in Sobolev spaces. Lecture Notes in Mathematics 571.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import RBFInterpolator

__all__: list[str] = []

#: Fewest ring samples for a fit to the ring (else the plane through the border data).
_MIN_RING = 12
#: Spline smoothing per fitted sample (scipy ``RBFInterpolator`` units, mm).
_SMOOTHING = 1e-3


class _SphereSpline:
    """Height field: one branch of a least-squares sphere plus a spline of the residual."""

    def __init__(self, samples: NDArray[np.float64], smoothing: float) -> None:
        x = samples
        design = np.column_stack([2.0 * x, np.ones(x.shape[0])])
        sol, *_ = np.linalg.lstsq(design, np.einsum("ij,ij->i", x, x), rcond=None)
        self.centre = sol[:3]
        r2 = sol[3] + self.centre @ self.centre
        self.radius = float(np.sqrt(r2)) if r2 > 0 else float("nan")
        self.sign = 1.0 if np.median(x[:, 2] - self.centre[2]) >= 0 else -1.0
        base = self.base(x[:, :2])
        self.valid = bool(np.all(np.isfinite(base)))
        self.spline = (
            RBFInterpolator(x[:, :2], x[:, 2] - base, kernel="thin_plate_spline", degree=1, smoothing=smoothing)
            if self.valid
            else None
        )

    def base(self, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        """Height of the sphere's branch over ``(u, v)``; NaN outside its disc."""
        q = self.radius**2 - np.einsum("ij,ij->i", uv - self.centre[:2], uv - self.centre[:2])
        out = np.full(uv.shape[0], np.nan)
        ok = q >= 0
        out[ok] = self.centre[2] + self.sign * np.sqrt(q[ok])
        return out

    def __call__(self, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        assert self.spline is not None
        return self.base(uv) + self.spline(uv)


class _Plane:
    """Least-squares plane ``h = a + b u + c v`` (the border of a hole ringed by walls)."""

    def __init__(self, samples: NDArray[np.float64]) -> None:
        design = np.column_stack([np.ones(samples.shape[0]), samples[:, 0], samples[:, 1]])
        self.coef, *_ = np.linalg.lstsq(design, samples[:, 2], rcond=None)

    def __call__(self, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.coef[0] + uv @ self.coef[1:]


class _Floor:
    """The plane z = z0 (world) as a height field over a hole's local frame."""

    def __init__(self, z0_local: float, e1: NDArray, e2: NDArray, normal: NDArray) -> None:
        self.z0, self.a, self.b, self.c = z0_local, float(e1[2]), float(e2[2]), float(normal[2])

    def __call__(self, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        return (self.z0 - uv[:, 0] * self.a - uv[:, 1] * self.b) / self.c


def _plain_spline(samples: NDArray[np.float64], smoothing: float) -> RBFInterpolator:
    """Thin-plate spline (linear polynomial part) of the heights over ``(u, v)``."""
    return RBFInterpolator(samples[:, :2], samples[:, 2], kernel="thin_plate_spline", degree=1, smoothing=smoothing)


def _fit(kind: str, samples: NDArray[np.float64]) -> Any:
    """A ``"sphere"`` (sphere plus spline, None if no sphere fits) or ``"spline"`` height field of the samples."""
    smoothing = _SMOOTHING * samples.shape[0]
    if kind == "sphere":
        model = _SphereSpline(samples, smoothing)
        return model if model.valid else None
    return _plain_spline(samples, smoothing)


def _rms(model: Any, samples: NDArray[np.float64]) -> float:
    """RMS height residual (mm) of a height field at the samples (infinite where it is undefined)."""
    r = model(samples[:, :2]) - samples[:, 2]
    return float(np.sqrt(np.mean(r * r))) if np.all(np.isfinite(r)) else float("inf")


def _sector_cv(kind: str, samples: NDArray[np.float64]) -> float:
    """RMS error predicting each quarter of the ring from the other three."""
    angle = np.arctan2(samples[:, 1] - samples[:, 1].mean(), samples[:, 0] - samples[:, 0].mean())
    sector = np.minimum(((angle + np.pi) / (0.5 * np.pi)).astype(np.int64), 3)
    err = []
    for k in range(4):
        test = sector == k
        if test.sum() < 3 or (~test).sum() < _MIN_RING:
            continue
        model = _fit(kind, samples[~test])
        if model is None:
            return float("inf")
        r = model(samples[test, :2]) - samples[test, 2]
        if not np.all(np.isfinite(r)):
            return float("inf")
        err.append(r * r)
    return float(np.sqrt(np.mean(np.concatenate(err)))) if err else float("inf")


def _choose_ring_model(samples: NDArray[np.float64], tolerance: float, cross_validate: bool) -> tuple[Any, str, float]:
    """Best of sphere + spline and plain spline on the ring, or (None, reason, rms)."""
    fitted = []
    worst = 0.0
    for kind in ("sphere", "spline"):
        try:
            model = _fit(kind, samples)
        except (np.linalg.LinAlgError, ValueError):
            model = None
        if model is None:
            continue
        rms = _rms(model, samples)
        worst = max(worst, rms)
        if rms <= tolerance:
            fitted.append((model, kind, rms))
    if not fitted:
        return None, f"no smooth height field fits the ring (RMS {worst:.3g} mm > {tolerance:.3g} mm)", worst
    if len(fitted) > 1 and cross_validate:
        scores = [_sector_cv(kind, samples) for _, kind, _ in fitted]
        return fitted[int(np.argmin(scores))]
    return fitted[0]
