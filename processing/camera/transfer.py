"""Chart transform from the object camera into the model camera: M2 of Matsuda et al., eq. (9).

The estimator is trained for a model camera (known sensitivities under a
known light).  The object is shot by another camera, or the same camera at
another exposure, together with a colour chart.  Matsuda et al. map that
camera into the model camera by ``M2 = rho_O rho_T^+`` (eq. (9)), the
least-squares 3 x 3 matrix between the chart patches as the reference (model)
camera sees them, ``rho_O`` (3 x k), and as the object camera recorded them,
``rho_T``; a pixel's weights are then ``w = M M2 rho_s`` (eq. (10)).  In the row-vector form of
:mod:`processing.spectral.estimation.fit` this is ``rho_model ~= rho_object @ T`` with
``T = pinv(rho_object) @ rho_model``.

With several exposures (two lights) each exposure has its own 3 x 3 block
and the transform is block-diagonal: exposures are not mixed.

The fit is ill-conditioned when the usable patches do not span three
independent colours, e.g. only the grey patches: the condition number
``sigma_1 / sigma_3`` of the object camera's patch matrix (per exposure) is
reported, and above ``max_condition`` (default 100; the 24-patch
ColorChecker gives about 10, its six greys about 2000) a
:class:`ChartConditionError` names it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.spectral.estimation.fit import SpectralEstimationError, checked_channels

__all__ = ["ChartConditionError", "ChartTransform", "fit_chart_transform", "condition_number"]

#: Largest accepted sigma_1 / sigma_3 of the chart's camera values.
MAX_CONDITION = 100.0


class ChartConditionError(SpectralEstimationError):
    """The chart patches do not constrain the fit (too few independent colours); the message gives the condition number."""

    def __init__(self, message: str, condition: float) -> None:
        super().__init__(message)
        self.condition = condition


@dataclass(frozen=True)
class ChartTransform:
    """A fitted chart transform.

    Attributes
    ----------
    matrix
        ``(c, c)`` row-form map ``rho_model ~= rho_object @ matrix``.
    condition
        Largest sigma_1 / sigma_3 over the exposures.
    residual
        RMS relative residual of the fit over the patches (fraction of the
        patch's model value).
    """

    matrix: NDArray[np.float64]
    condition: float
    residual: float


def condition_number(values: ArrayLike, rank: int = 3) -> float:
    """``sigma_1 / sigma_rank`` of a matrix (inf when it has fewer than ``rank`` independent rows).

    Examples
    --------
    >>> condition_number(np.eye(3))
    1.0
    >>> condition_number([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]])
    inf
    """
    sv = np.linalg.svd(np.asarray(values, dtype=np.float64), compute_uv=False)
    if sv.size < rank or sv[0] == 0 or sv[rank - 1] <= sv[0] * 1e-15:
        return float("inf")
    return float(sv[0] / sv[rank - 1])


def fit_chart_transform(
    object_rgb: ArrayLike, model_rgb: ArrayLike, *, max_condition: float = MAX_CONDITION
) -> ChartTransform:
    """Fit M2 from the chart patches: ``(n, c)`` object-camera values against the model camera's.

    Parameters
    ----------
    object_rgb
        Patch values recorded by the object camera, ``(n, c)``, c a multiple of 3.
    model_rgb
        The same patches through the model camera, ``(n, c)``.
    max_condition
        Largest accepted condition number (see the module text).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> model = rng.uniform(0.05, 1, (24, 3))
    >>> t = np.array([[1.1, 0.1, 0], [0, 0.9, 0.05], [0, 0, 1.2]])
    >>> fit = fit_chart_transform(model @ np.linalg.inv(t), model)
    >>> bool(np.allclose(fit.matrix, t))
    True
    """
    obj = checked_channels("chart object_rgb", object_rgb)
    mod = checked_channels("chart model_rgb", model_rgb)
    obj = np.asarray(obj, dtype=np.float64)
    mod = np.asarray(mod, dtype=np.float64)
    if obj.ndim != 2 or obj.shape != mod.shape:
        raise SpectralEstimationError(
            f"chart object_rgb and model_rgb must both be (patches, channels), got {obj.shape} and {mod.shape}"
        )
    n, c = obj.shape
    if c % 3:
        raise SpectralEstimationError(f"chart values need 3 channels per exposure, got {c}")
    if n < 3:
        raise ChartConditionError(f"the chart transform needs at least 3 patches, got {n}", float("inf"))
    matrix = np.zeros((c, c))
    worst = 1.0
    for k in range(0, c, 3):
        block = obj[:, k:k + 3]
        cond = condition_number(block)
        worst = max(worst, cond)
        if not cond <= max_condition:
            raise ChartConditionError(
                f"the chart patches do not fix the camera transform (exposure {k // 3 + 1}): condition number "
                f"{cond:.3g} > {max_condition:g}; use patches of at least three distinct colours, not only greys",
                cond,
            )
        matrix[k:k + 3, k:k + 3] = np.linalg.lstsq(block, mod[:, k:k + 3], rcond=None)[0]
    scale = np.maximum(np.abs(mod), 1e-12)
    residual = float(np.sqrt(np.mean(((obj @ matrix - mod) / scale) ** 2)))
    return ChartTransform(matrix, worst, residual)
