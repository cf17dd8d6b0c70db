"""Camera: RAW decoding, colour charts, the camera's spectral model and its calibration to a chart.

Modules
-------
raw_decode
    Linear, un-white-balanced camera RGB and masks from a Bayer RAW file; the sRGB preview.
cfa_fringe
    The false colour of a binned Bayer image where the brightness changes fast (small highlights).
chart_layout
    Patch geometry and reference colours of the charts ``cv2.mcc`` knows.
chart_detection
    Where each patch of a chart lies in a frame (``cv2.mcc`` and refinement, or four corners).
chart_sampling
    Patch statistics of the linear RGB, and the checks that reject an unusable chart shot.
response
    Spectral sensitivities and the linear camera response to reflectance under lights.
transfer
    The chart transform M2 from the object camera into the model camera.
from_chart
    Smooth non-negative sensitivities estimated from a chart of known reflectances.
charuco
    ChArUco board definitions and their checked, sub-pixel detection in a linear frame.
point_spread
    The lens and low-pass filter's point spread, by matching posed renderings to their photos.

The function ``chart_layout`` shares its module's name, so this front door
does not export it (the package attribute stays the module); use
``from processing.camera.chart_layout import chart_layout``.
docs/colour-pipeline.md describes the whole pipeline.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of a
craft object based on a light reflection model", IPSJ technical report
(no DOI), section 4.1, eq. (9)-(10).

Gunturk, B. K., Glotzbach, J., Altunbasak, Y., Schafer, R. W., Mersereau,
R. M. (2005). Demosaicking: color filter array interpolation. IEEE Signal
Processing Magazine 22(1), 44-54. doi:10.1109/MSP.2005.1407714

Marrero Fernandez, P. D., Guerrero-Pena, F. A., Ren, T. I., et al. (2019).
Fast and robust multiple ColorChecker detection using deep convolutional
neural networks. Image and Vision Computing 81 (arXiv:1810.08639).

Jiang, J., Liu, D., Gu, J., Susstrunk, S. (2013). What is the space of
spectral sensitivity functions for digital color cameras? IEEE WACV, 168-179.
doi:10.1109/WACV.2013.6475015
"""

from processing.camera.cfa_fringe import CfaFringeError, cfa_fringe, transformed_fringe
from processing.camera.chart_detection import (
    ChartDetection,
    ChartDetectionError,
    ChartNotFoundError,
    ChartOutsideError,
    chart_from_corners,
    detect_chart,
    parse_corners,
)
from processing.camera.chart_layout import (
    CHARTS,
    ChartLayout,
    ChartLayoutError,
    reference_lab,
    reference_srgb8,
)
from processing.camera.chart_sampling import (
    ChartCheck,
    ChartRejectedError,
    ChartSamplingError,
    PatchSamples,
    check_patches,
    sample_patches,
)
from processing.camera.from_chart import SensitivityFit, estimate_sensitivities
from processing.camera.point_spread import PointSpreadError, PointSpreadFit, fit_point_spread, spread_within
from processing.camera.raw_decode import (
    DECODE_MODES,
    RawDecodeError,
    RawImage,
    bilinear_demosaic,
    bin2x2,
    decode_raw,
    preview_srgb8,
    sniff_format,
)
from processing.camera.response import (
    DEFAULT_CAMERA,
    CameraResponseError,
    camera_names,
    camera_rgb,
    camera_sensitivities,
    channel_matrix,
)
from processing.camera.transfer import ChartConditionError, ChartTransform, condition_number, fit_chart_transform

__all__ = [
    # raw_decode
    "DECODE_MODES",
    "RawDecodeError",
    "RawImage",
    "decode_raw",
    "bin2x2",
    "bilinear_demosaic",
    "preview_srgb8",
    "sniff_format",
    # cfa_fringe
    "CfaFringeError",
    "cfa_fringe",
    "transformed_fringe",
    # point_spread
    "PointSpreadError",
    "PointSpreadFit",
    "fit_point_spread",
    "spread_within",
    # chart_layout
    "CHARTS",
    "ChartLayout",
    "ChartLayoutError",
    "reference_srgb8",
    "reference_lab",
    # chart_detection
    "ChartDetection",
    "ChartDetectionError",
    "ChartNotFoundError",
    "ChartOutsideError",
    "detect_chart",
    "chart_from_corners",
    "parse_corners",
    # chart_sampling
    "ChartCheck",
    "ChartRejectedError",
    "ChartSamplingError",
    "PatchSamples",
    "check_patches",
    "sample_patches",
    # response
    "DEFAULT_CAMERA",
    "CameraResponseError",
    "camera_names",
    "camera_sensitivities",
    "channel_matrix",
    "camera_rgb",
    # transfer
    "ChartConditionError",
    "ChartTransform",
    "fit_chart_transform",
    "condition_number",
    # from_chart
    "SensitivityFit",
    "estimate_sensitivities",
]
