"""Chart transform from the object camera into the model camera: M2 of Matsuda et al., eq. (9).

The least-squares 3 x 3 map between the chart patches as the object camera
recorded them and as the model camera sees them, one block per exposure,
``rho_model ~= rho_object @ T`` (the row form of ``M2 = rho_O rho_T^+``), with
the condition number that says whether the patches fix it.
docs/colour-pipeline.md, "Object camera -> model camera", gives the
derivation and the thresholds.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of a
craft object based on a light reflection model", IPSJ technical report
(no DOI), section 4.1, eq. (9)-(10).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.spectral.checks import SpectralEstimationError, checked_channels

__all__ = ["ChartConditionError", "ChartTransform", "fit_chart_transform", "condition_number", "READ_NOISE",
           "transformed_read_noise"]

#: Largest accepted sigma_1 / sigma_3 of the chart's camera values.
MAX_CONDITION = 100.0
#: Read noise of one photosite after black subtraction, as a fraction of full scale, assumed when the RAW does
#: not state it: about 5 DN of a 14-bit sensor (cameras at base ISO read 1.5-5 DN; the simulated sensor 2 DN of
#: its 15 783), taken at the upper end because it is a floor under the colour of dark pixels.
READ_NOISE = 3e-4


class ChartConditionError(SpectralEstimationError):
    """The chart patches do not constrain the fit (too few independent colours); the message gives the condition number.

    Parameters
    ----------
    message
        What is wrong and what to do.
    condition
        The condition number found (inf when there are too few patches).

    Attributes
    ----------
    condition
        The condition number found.
    """

    def __init__(self, message: str, condition: float) -> None:
        super().__init__(message)
        self.condition = condition


@dataclass(frozen=True)
class ChartTransform:
    """A fitted chart transform.

    Parameters
    ----------
    matrix, condition, residual
        The attributes below, in this order.

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

    Parameters
    ----------
    values
        A 2-D matrix, e.g. ``(patches, 3)`` camera values.
    rank
        Which singular value divides the largest (1-based).

    Returns
    -------
    float
        The ratio, >= 1; inf when ``sigma_rank`` is 0 or below ``1e-15 sigma_1``.

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

    With several exposures (two lights) each has its own 3 x 3 block and the
    transform is block-diagonal: exposures are not mixed.  The fit is refused
    when the object camera's patch values of an exposure have a condition
    number ``sigma_1 / sigma_3`` above ``max_condition`` (the 24-patch
    ColorChecker gives about 10, its six greys about 2000).

    Parameters
    ----------
    object_rgb
        Patch values recorded by the object camera, ``(n, c)``, c a multiple of 3
        (linear, >= 0).
    model_rgb
        The same patches through the model camera, ``(n, c)``.
    max_condition
        Largest accepted condition number.

    Returns
    -------
    ChartTransform
        The ``(c, c)`` row-form matrix, the worst condition number over the
        exposures and the RMS relative residual.

    Raises
    ------
    SpectralEstimationError
        Bad values, shapes that differ, or channels not a multiple of 3.
    ChartConditionError
        Fewer than 3 patches, or a condition number above ``max_condition``.

    References
    ----------
    Matsuda et al., IPSJ technical report (no DOI), section 4.1, eq. (9).

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


def transformed_read_noise(matrix: ArrayLike, read_noise: float = READ_NOISE, mode: str = "bin2x2") -> NDArray[np.float64]:
    """``(3, 3)`` covariance of one pixel's read noise in the model camera's units.

    A photosite's read noise ``s`` (fraction of full scale) becomes, per decoded channel, ``s``
    for red and blue and ``s / sqrt(2)`` for the mean of the two greens of a ``bin2x2`` pixel (``s``
    in every channel otherwise, a demosaicked pixel being at least one photosite's noise); the row-form
    chart transform ``M`` carries the diagonal covariance ``D`` to ``M.T @ D @ M``.  It is the
    ``dark_noise`` of :func:`processing.materials.identification.identify_material`: the noise floor
    whose clipped values read as the colour the transform gives a RAW grey.

    Parameters
    ----------
    matrix
        ``(3, 3)`` row-form chart transform (:attr:`ChartTransform.matrix`).
    read_noise
        One photosite's read noise, fraction of full scale (>= 0).
    mode
        The decode: ``"bin2x2"`` or a demosaicking mode.

    Returns
    -------
    ndarray
        ``(3, 3)`` covariance.

    Raises
    ------
    SpectralEstimationError
        A matrix that is not 3 x 3 and finite, or a negative or non-finite ``read_noise``.

    Examples
    --------
    >>> c = transformed_read_noise(np.diag([2.0, 1.0, 1.5]), 1e-3)
    >>> np.round(np.sqrt(np.diag(c)) * 1e3, 3).tolist()
    [2.0, 0.707, 1.5]
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise SpectralEstimationError(f"chart transform must be a finite 3 x 3 matrix, got shape {m.shape}")
    if not (isinstance(read_noise, (int, float, np.floating)) and np.isfinite(read_noise) and read_noise >= 0):
        raise SpectralEstimationError(f"read_noise must be a fraction of full scale >= 0, got {read_noise!r}")
    per = float(read_noise) * (np.array([1.0, np.sqrt(0.5), 1.0]) if mode == "bin2x2" else np.ones(3))
    return m.T @ np.diag(per**2) @ m
