"""Spectral estimation: reflectance from camera values, one module per estimator, one result type.

Modules
-------
fit
    :class:`SpectralFit`, the form every estimator ends in, and the shared
    PCA basis, root-polynomial features and input checks.
pca_matsuda
    The paper's estimator: PCA basis with p = 3 and a 3 x 3 least-squares M.
wiener
    Wiener (linear MMSE) estimation with known sensitivities and light.
root_polynomial_finlayson
    Root-polynomial (or linear, 'more-basis') ridge regression onto a larger PCA basis.
two_light
    Two exposures under two lights: six channels.
estimator
    :data:`METHODS` and :func:`fit_estimator` (by name, calibrated to a
    chart), spectral images and region spectra.
metamer_set
    The luminances a camera's values allow: bounds over its metamer set.

docs/colour-pipeline.md, "Spectral estimation and material identification",
describes the methods and their accuracy.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of a
craft object based on a light reflection model", IPSJ technical report
(no DOI), section 4.1, eq. (6)-(10).

Pratt, W. K., Mancill, C. E. (1976). Spectral estimation techniques for the
spectral calibration of a color image scanner. Applied Optics 15(1), 73-75.
doi:10.1364/AO.15.000073

Finlayson, G. D., Morovic, P. (2005). Metamer sets. Journal of the Optical
Society of America A 22(5), 810-819. doi:10.1364/JOSAA.22.000810

Finlayson, G. D., Mackiewicz, M., Hurlbert, A. (2015). Color correction using
root-polynomial regression. IEEE Transactions on Image Processing 24(5),
1460-1470. doi:10.1109/TIP.2015.2405336
"""

from processing.spectral.estimation.estimator import (
    METHODS,
    RegionSpectra,
    SpectralImage,
    fit_estimator,
    reflectance_from_weights,
    region_spectra,
    spectral_image,
)
from processing.spectral.estimation.fit import (
    SpectralEstimationError,
    SpectralFit,
    checked_channels,
    checked_spectra,
    expand_features,
    feature_names,
    pca_basis,
    with_transform,
)
from processing.spectral.estimation.metamer_set import luminance_range
from processing.spectral.estimation.pca_matsuda import fit_paper
from processing.spectral.estimation.root_polynomial_finlayson import fit_more_basis, fit_rootpoly
from processing.spectral.estimation.two_light import fit_two_light
from processing.spectral.estimation.wiener import cross_validated_noise, fit_wiener, wiener_matrix

__all__ = [
    # estimator
    "METHODS",
    "fit_estimator",
    "SpectralImage",
    "spectral_image",
    "reflectance_from_weights",
    "RegionSpectra",
    "region_spectra",
    # fit
    "SpectralEstimationError",
    "SpectralFit",
    "pca_basis",
    "checked_channels",
    "checked_spectra",
    "feature_names",
    "expand_features",
    "with_transform",
    # metamer_set
    "luminance_range",
    # pca_matsuda
    "fit_paper",
    # wiener
    "wiener_matrix",
    "fit_wiener",
    "cross_validated_noise",
    # root_polynomial_finlayson
    "fit_rootpoly",
    "fit_more_basis",
    # two_light
    "fit_two_light",
]
