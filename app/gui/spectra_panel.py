"""Spectra and materials panel: click on an object frame to plot the estimated reflectance (with its
uncertainty) against the identified material's model spectrum; a material map over the frame.

A display over the colour pipeline's workflow (docs/colour-pipeline.md):

1. the frame and the pass's chart frame go through the same chain as
   ``kogei spectral estimate``: :func:`app.workflows.chart.measure_chart`
   and :func:`app.workflows.spectral.estimate_from_chart` (Matsuda et al.,
   section 4.1, eq. (6)-(10), or a better method, calibrated to the chart
   with the chart transform M2, eq. (9)), giving per-pixel basis weights, the
   image in the model camera's units and the mask of saturated or dead
   pixels, identical to the command's for the same frames;
2. a clicked point: the mean reflectance of the unmasked pixels around it
   with its uncertainty (pixel spread and the estimate's error on the chart
   in quadrature, :func:`processing.spectral.estimation.estimator.region_spectra`);
3. its material (Matsuda et al., section 4.2, eq. (11)): the candidate whose
   forward-modelled camera colour is nearest
   (:func:`processing.materials.identification.identify_material` on the
   chart-transformed camera values); the candidate's model spectrum is its
   reflectance factor at the identification geometry
   (:func:`processing.materials.lobes.material_brdf` times pi cos_i), scaled to the
   measured spectrum by least squares for the plot (brightness is a free
   parameter of the identification);
4. the material map: the same identification over square blocks of the frame
   (:func:`processing.materials.identification.identify_regions`), leaving out
   pixels too dark to have a colour, masked pixels and the backdrop (the
   colour of the frame's rim), and blocks left less than half full.

A click is refused, with the reason, where there is nothing to measure:
a clipped pixel, a pixel too dark to have a colour (green below
:data:`MIN_SIGNAL` of full scale), or the backdrop.  Both identifications
answer through the project's one confidence rule
(:func:`processing.materials.confidence.decide`): "no candidate fits" when
even the best candidate misses the colour by far more than its stated
error, "neutral metal" when silver-like metals cannot be told apart.  The
map says how much of the object it judged and why the rest was left out
(:func:`map_coverage`).  With "only the catalogued materials" on, the
candidates are the session's catalogued materials
(:func:`catalogued_candidates`: "shibuichi, gold, urushi" -> the shibuichi
alloys, gold and both lacquers) rather than every preset.

Both identifications carry the colour error the ``bin2x2`` decode puts into a
small highlight or an edge (red and blue sampled on either side of a steep
brightness change: :func:`processing.camera.cfa_fringe.transformed_fringe`,
stored on the scene as ``fringe``), so a grey highlight a few pixels wide is
not named gold with confidence; a mixed group below :data:`CANNOT_TELL` reads
"cannot tell" with the short list (:func:`answer_text`, :func:`answer_title`).
They also carry the sensor's read noise through the chart transform
(:func:`processing.camera.transfer.transformed_read_noise`, stored as
``dark_noise``): pixels at the noise floor, such as the dark flank of a
highlight, hold clipped noise that the transform turns red, not a colour;
and the transform itself (``transform``), so that the relative noise and model
error are taken in the sensor's channels, where they arise, and carried
through it.

Both identifications allow the candidates the same model error as the batch
``materials`` step (:data:`app.batch.materials.MODEL_ERROR`, 1.75 %): the
shibuichi alloys, shakudo and bronze differ by 0.005-0.02 in camera
chromaticity, about what one block of a highlight varies by on polished
metal, so a block map tells families apart (gold, copper-rich, silver-rich,
lacquer) far better than the alloys of a family; regions pooled over a
whole part (``kogei identify``, the batch step) separate the alloys.

Examples
--------
>>> block_labels((4, 6), 2).tolist()
[[1, 1, 2, 2, 3, 3], [1, 1, 2, 2, 3, 3], [4, 4, 5, 5, 6, 6], [4, 4, 5, 5, 6, 6]]
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QPixmap
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QFrame,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QScrollArea,
    QSizePolicy,
    QSpinBox,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from app.batch.materials import MODEL_ERROR
from app.gui.figures import empty_figure, spectrum_figure
from app.gui.plots import FigureDrawer, PlotImage
from app.gui.session_panel import rgb_to_qimage
from app.gui.widgets import Panel, WrapLabel
from app.gui.workers import JobContext, Lane

__all__ = ["SpectraPanel", "SpectralScene", "analyse_spectra", "spectrum_at", "material_map", "UNCERTAIN",
           "backdrop_mask", "block_labels", "LIGHT_DEG", "catalogued_candidates", "map_coverage", "answer_text",
           "answer_title", "CANNOT_TELL"]

#: Angle of the light from the surface normal assumed by the identification (degrees).
LIGHT_DEG = 30.0
#: Green signal (fraction of full scale) below which a pixel has no measurable colour (as the camera panel's
#: 'dark' patches: quantisation and read noise dominate).
MIN_SIGNAL = 0.02


def block_labels(shape: tuple[int, int], block: int) -> np.ndarray:
    """Labels 1.. of square ``block`` x ``block`` tiles over an image of ``shape`` (row-major)."""
    h, w = shape
    rows = np.arange(h)[:, None] // block
    cols = np.arange(w)[None, :] // block
    return (rows * ((w + block - 1) // block) + cols + 1).astype(np.int64)


def catalogued_candidates(text: str) -> tuple[list[str], list[str]]:
    """The identification's candidates named by a catalogue entry, and the words that name none.

    Words are separated by commas, semicolons or "and"; a word picks the
    candidates it names whole or as a hyphenated part ("shibuichi": every
    shibuichi alloy; "urushi": black and red lacquer).

    Examples
    --------
    >>> catalogued_candidates("shibuichi, gold and Urushi; enamel")
    (['nami-shibuichi', 'shiro-shibuichi', 'jo-shibuichi', 'nami-shibuichi-uchi-sanbu', 'nami-shibuichi-soto-sanbu', 'gold', 'urushi-black', 'urushi-red'], ['enamel'])
    """
    import re

    from processing.materials.identification import DEFAULT_CANDIDATES

    words = [w.strip().lower() for w in re.split(r"[,;]|\band\b", text) if w.strip()]
    names: list[str] = []
    unmatched: list[str] = []
    for word in words:
        hits = [c for c in DEFAULT_CANDIDATES if c == word or word in c.split("-")]
        if not hits:
            unmatched.append(word)
        names.extend(h for h in hits if h not in names)
    return names, unmatched


#: Below this confidence, an answer whose group holds other candidates reads "cannot tell" with the short list.
CANNOT_TELL = 0.5


def _short_list(group: tuple[str, ...], shown: int = 4) -> str:
    more = len(group) - shown
    return ", ".join(group[:shown]) + (f" and {more} more" if more > 0 else "")


def answer_title(ident: Any) -> str:
    """A few words for the plot's title: the name and its confidence, or what cannot be told apart."""
    from processing.materials.confidence import NEUTRAL_METAL, NO_FIT

    if ident.material in (NO_FIT, NEUTRAL_METAL):
        return ident.material
    if len(ident.group) > 1 and ident.confidence < CANNOT_TELL:
        return f"cannot tell ({len(ident.group)} fit)"
    return f"{ident.material}, confidence {ident.confidence:.2f}"


def answer_text(ident: Any, colour_error: float = 0.0) -> str:
    """One line for an identification's answer, what the confidence is of, and the alternatives.

    ``colour_error``: the largest relative colour error the decode predicts for the clicked region (its CFA
    fringe); above 5 % the line says so, as the reason a short list is all one click can give.
    """
    from processing.materials.confidence import NEUTRAL_METAL, NO_FIT

    why = (f"; a steep highlight or edge: the sensor's colour filter shifts its colour by up to "
           f"{100 * colour_error:.0f}%" if colour_error > 0.05 else "")
    if ident.material == NO_FIT:
        return (f"no candidate fits: the nearest ({', '.join(ident.group)}) miss its colour by "
                f"{math.sqrt(ident.misfit):.1f} times the stated error")
    if ident.material == NEUTRAL_METAL:
        return (f"a neutral metal, one of {', '.join(ident.group)} (confidence {ident.confidence:.2f}; they differ "
                f"mainly in brightness{why})")
    if len(ident.group) > 1 and ident.confidence < CANNOT_TELL:
        return (f"cannot tell: {_short_list(ident.group)} fit about equally (best {ident.material}, confidence "
                f"{ident.confidence:.2f}{why})")
    return f"{ident.material} (confidence {ident.confidence:.2f}, runner-up {ident.runner_up}{why})"


@dataclass
class SpectralScene:
    """An object frame with its chart-calibrated estimate."""

    frame: Path
    chart_frame: Path
    preview: np.ndarray            # (H, W, 3) uint8
    rgb: np.ndarray                # (H, W, 3) linear object-camera RGB, negatives clipped (dark and backdrop tests)
    estimate: Any                  # app.workflows.spectral.ChartEstimate: weights, model-camera image, mask, fit
    candidates: Any                # processing.materials.identification.CandidateSet
    method_error: float
    usable_patches: int
    light: str
    clipped: np.ndarray | None = None   # (H, W) bool: a photosite of the pixel saturated or dead (not estimated)
    backdrop: np.ndarray | None = None  # (H, W) bool: the backdrop (backdrop_mask)
    fringe: np.ndarray | None = None    # (H, W, c) relative colour error of the binned CFA, model camera
    dark_noise: np.ndarray | None = None  # (c, c) one pixel's read noise in the model camera (transformed_read_noise)
    transform: np.ndarray | None = None   # (c, c) the chart transform from the object camera to the model camera

    @property
    def fit(self) -> Any:
        """The calibrated estimator (:class:`processing.spectral.estimation.fit.SpectralFit`)."""
        return self.estimate.fit


def analyse_spectra(frame: str | Path, chart_frame: str | Path, *, light: str = "D65", method: str = "wiener",
                    chart: str = "classic24", corners: str | None = None,
                    materials: list[str] | None = None) -> SpectralScene:
    """Decode the frame, estimate it through the chart exactly as ``kogei spectral estimate`` does, model the candidates.

    ``corners``: the chart's outer corners marked by hand (``--chart-corners``' text) instead of looking for it;
    ``materials``: the candidate materials (default every preset).
    """
    from app.workflows.chart import measure_chart
    from app.workflows.spectral import estimate_from_chart, estimator_setup
    from processing.camera.cfa_fringe import transformed_fringe
    from processing.camera.raw_decode import decode_raw, preview_srgb8
    from processing.camera.transfer import transformed_read_noise
    from processing.materials.identification import candidate_set

    if chart != "classic24":
        raise ValueError(f"chart {chart!r}: the spectra are calibrated with the ColorChecker Classic (classic24)")
    setup = estimator_setup(light=light, chart_type=chart)
    obj = decode_raw(frame, mode="bin2x2")
    est = estimate_from_chart([obj], [measure_chart(Path(chart_frame), chart=chart, corners=corners)], setup,
                              method=method,
                              image_name=f"{frame}", chart_name=f"{chart_frame}")
    # black subtraction leaves read noise of either sign around 0
    rgb = np.maximum(obj.rgb, 0.0)
    return SpectralScene(Path(frame), Path(chart_frame), preview_srgb8(obj), rgb, est,
                         candidate_set(setup.sensitivities, setup.lights[0], setup.grid,
                                       light_deg=LIGHT_DEG, **({} if materials is None else {"names": materials})),
                         est.chart_rmse, int(est.usable.sum()), light, ~est.mask, backdrop_mask(rgb),
                         transformed_fringe(rgb, obj.cfa_pattern, est.transform.matrix),
                         transformed_read_noise(est.transform.matrix, mode="bin2x2"),
                         np.asarray(est.transform.matrix, dtype=np.float64))


def spectrum_at(scene: SpectralScene, x: int, y: int, radius: int = 2) -> dict[str, Any]:
    """Reflectance around image pixel ``(x, y)`` with its uncertainty, the material and its model spectrum."""
    from processing.materials.identification import identify_material
    from processing.materials.lobes import material_brdf
    from processing.materials.presets import get_material
    from processing.spectral.estimation.estimator import region_spectra

    h, w = scene.rgb.shape[:2]
    if not (0 <= x < w and 0 <= y < h):
        raise ValueError(f"pixel ({x}, {y}) is outside the {w} x {h} frame")
    y0, y1, x0, x1 = max(y - radius, 0), min(y + radius + 1, h), max(x - radius, 0), min(x + radius + 1, w)
    keep = (np.ones((y1 - y0, x1 - x0), bool) if scene.clipped is None else ~scene.clipped[y0:y1, x0:x1])
    if not keep.any():
        raise ValueError(f"pixel ({x}, {y}) and its neighbours are clipped (saturated): their colour cannot be "
                         "measured; click a less bright part of the object, or shoot with less exposure")
    green = float(scene.rgb[y0:y1, x0:x1, 1][keep].mean())
    if green < MIN_SIGNAL:
        raise ValueError(f"pixel ({x}, {y}) is too dark to measure a colour: its signal is {100 * green:.1f}% of full "
                         f"scale, below {100 * MIN_SIGNAL:.0f}%; click a lit part of the object")
    if scene.backdrop is not None and scene.backdrop[y, x]:
        raise ValueError(f"pixel ({x}, {y}) is the backdrop, not the object: click the object")
    weights = scene.estimate.weights[y0:y1, x0:x1][keep][:, None, :]      # the kept pixels, as (N, 1, p)
    reg = region_spectra(weights, np.ones(weights.shape[:2], np.int64), scene.fit.basis, scene.method_error)
    camera = scene.estimate.camera[y0:y1, x0:x1][keep].astype(np.float64)
    fringe = None if scene.fringe is None else scene.fringe[y0:y1, x0:x1][keep]
    ident = identify_material(camera, scene.candidates, model_error=MODEL_ERROR, colour_error=fringe,
                              dark_noise=scene.dark_noise, transform=scene.transform)
    wl = scene.fit.wavelengths
    name = ident.material if ident.material in scene.candidates.names else ident.group[0]
    t = math.radians(LIGHT_DEG)
    mat = get_material(name)
    model = material_brdf(mat, math.cos(t), 1.0, math.cos(t / 2), math.cos(t / 2), wl) * (math.pi * math.cos(t))
    mean = reg.mean[0]
    k = float(model @ mean / max(model @ model, 1e-300))
    return {"x": x, "y": y, "wavelengths": wl, "mean": mean, "uncertainty": reg.uncertainty[0],
            "identification": ident, "model_name": name, "model": model * k, "model_scale": k,
            "pixels": int(reg.count[0]),
            "colour_error": 0.0 if fringe is None else float(np.abs(fringe).max(initial=0.0))}


def backdrop_mask(rgb: np.ndarray, tolerance: float = 0.15, rim: float = 0.05) -> np.ndarray:
    """Pixels of the backdrop: within ``tolerance`` (relative, per channel) of the median colour of the frame's rim.

    The object stands in the middle of the frame on a uniform backdrop, so the
    outer ``rim`` fraction of the frame is backdrop.

    Examples
    --------
    >>> img = np.full((20, 20, 3), 0.2); img[8:12, 8:12] = [0.6, 0.3, 0.1]
    >>> int(backdrop_mask(img).sum())
    384
    """
    h, w = rgb.shape[:2]
    k = max(1, int(round(rim * min(h, w))))
    border = np.concatenate([rgb[:k].reshape(-1, 3), rgb[-k:].reshape(-1, 3), rgb[:, :k].reshape(-1, 3),
                             rgb[:, -k:].reshape(-1, 3)])
    ref = np.median(border, axis=0)
    return np.all(np.abs(rgb - ref) <= tolerance * np.maximum(ref, 1e-6), axis=2)


#: Name of the map's label for blocks identified with too little confidence to name a material.
UNCERTAIN = "uncertain"


def material_map(scene: SpectralScene, block: int = 6, min_signal: float = MIN_SIGNAL,
                 min_confidence: float = 0.5) -> tuple[np.ndarray, dict[int, str]]:
    """Material of each ``block`` x ``block`` tile of the object; returns labels and their names.

    Label 0: not judged -- too dark (green below ``min_signal`` of full
    scale: no colour to measure), clipped (a photosite saturated or dead:
    the colour is wrong, and the estimate leaves it out), the backdrop (:func:`backdrop_mask`), or a block
    with fewer than half its pixels left (the rim of a highlight or of the
    object: too few pixels to average).
    A tile whose best candidate has a confidence below ``min_confidence``
    (:func:`processing.materials.identification.identify_material`: the
    posterior probability among the candidates) is labelled
    :data:`UNCERTAIN` rather than given a name it may not have -- on
    polished metal lit by one lamp, tiles at the edge of a highlight often
    fit two or three alloys about equally.
    """
    from processing.materials.identification import identify_regions

    if not 0.0 <= min_confidence <= 1.0:
        raise ValueError(f"min_confidence must be within 0..1, got {min_confidence!r}")
    h, w = scene.rgb.shape[:2]
    labels = block_labels((h, w), block)
    skip = (scene.rgb[..., 1] < min_signal) | (backdrop_mask(scene.rgb) if scene.backdrop is None else scene.backdrop)
    if scene.clipped is not None:
        skip |= scene.clipped
    labels = np.where(skip, 0, labels)
    ids, counts = np.unique(labels[labels > 0], return_counts=True)
    labels = np.where(np.isin(labels, ids[counts < (block * block + 1) // 2]), 0, labels)
    if not labels.any():
        raise ValueError("no block of the frame is at least half lit, unclipped and unlike the backdrop: nothing "
                         "to identify (a smaller block may do)")
    model = scene.estimate.camera.astype(np.float64)
    found = identify_regions(model, labels, scene.candidates, model_error=MODEL_ERROR, colour_error=scene.fringe,
                             dark_noise=scene.dark_noise, transform=scene.transform)
    named = {int(lab): UNCERTAIN for lab in np.unique(labels[labels > 0])}    # a block of fringe only: uncertain
    named.update({lab: (r.material if r.confidence >= min_confidence else UNCERTAIN) for lab, r in found.items()})
    names = sorted(set(named.values()) - {UNCERTAIN}) + ([UNCERTAIN] if UNCERTAIN in named.values() else [])
    index = {n: i + 1 for i, n in enumerate(names)}
    lut = np.zeros(int(labels.max()) + 1, np.int64)
    for lab, name in named.items():
        lut[lab] = index[name]
    return lut[labels], {i: n for n, i in index.items()}


def map_coverage(scene: SpectralScene, labels: np.ndarray, min_signal: float = MIN_SIGNAL) -> dict[str, int]:
    """How much of the object a material map judged, and why the rest was left out (pixel counts).

    The object is every pixel but the backdrop; of it, ``judged`` pixels got
    a label, the others are ``dark``, ``clipped``, or ``sparse`` (in a block
    less than half usable), counted in that order.
    """
    back = scene.backdrop if scene.backdrop is not None else backdrop_mask(scene.rgb)
    obj = ~back
    dark = obj & (scene.rgb[..., 1] < min_signal)
    clipped = obj & ~dark & (scene.clipped if scene.clipped is not None else False)
    judged = obj & (labels > 0)
    return {"object": int(obj.sum()), "judged": int(judged.sum()), "dark": int(dark.sum()),
            "clipped": int(clipped.sum()), "sparse": int((obj & ~dark & ~clipped & ~judged).sum())}


def _map_colours(names: dict[int, str]) -> np.ndarray:
    """Row 0 black, then a colour per label (Matplotlib's tab20 less its greys); :data:`UNCERTAIN` grey."""
    import matplotlib

    n = max(names, default=0)
    tab = matplotlib.colormaps["tab20"](np.r_[0:14, 16:20])[:, :3]         # tab20's 14 and 15 are greys
    out = np.vstack([[0, 0, 0], np.round(255 * tab[np.arange(n) % len(tab)])]).astype(np.uint8)
    for i, name in names.items():
        if name == UNCERTAIN:
            out[i] = (150, 150, 150)
    return out


class _ClickImage(QLabel):
    clicked = Signal(int, int)

    def __init__(self) -> None:
        super().__init__()
        self.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.setMinimumSize(320, 240)
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Ignored)
        self.setStyleSheet("background:#202020; color:#ddd;")
        self.image_size: tuple[int, int] | None = None       # (w, h) of the image shown
        self._rect = None

    def show_rgb(self, rgb: np.ndarray) -> None:
        h, w = rgb.shape[:2]
        self.image_size = (w, h)
        pix = QPixmap.fromImage(rgb_to_qimage(rgb)).scaled(self.size(), Qt.AspectRatioMode.KeepAspectRatio,
                                                             Qt.TransformationMode.FastTransformation)
        self.setPixmap(pix)
        ox, oy = (self.width() - pix.width()) / 2, (self.height() - pix.height()) / 2
        self._rect = (ox, oy, pix.width() / w, pix.height() / h)

    def mousePressEvent(self, e: Any) -> None:  # noqa: N802
        if self._rect is None or self.image_size is None:
            return
        ox, oy, sx, sy = self._rect
        p = e.position()
        x, y = int((p.x() - ox) / sx), int((p.y() - oy) / sy)
        if 0 <= x < self.image_size[0] and 0 <= y < self.image_size[1]:
            self.clicked.emit(x, y)


class SpectraPanel(Panel):
    """See the module docstring."""

    analysed = Signal(object)          # spectrum_at's dict
    map_ready = Signal()

    def __init__(self, lane: Lane, drawer: FigureDrawer, session_root: Callable[[], Path | None],
                 parent: QWidget | None = None, catalogue: Callable[[], str] | None = None) -> None:
        super().__init__(parent)
        self.lane = lane
        self.session_root = session_root
        #: The session's catalogued materials (the Session tab's "Materials (as catalogued)").
        self.catalogue = catalogue or (lambda: "")
        self.scene: SpectralScene | None = None
        self.last: dict[str, Any] | None = None
        self.map: tuple[np.ndarray, dict[int, str]] | None = None
        self.manual_corners: dict[str, str] = {}
        self._requests = 0
        self._clicks = 0
        outer = QHBoxLayout(self)
        # the controls, the state and the legend scroll together: in a small window nothing is cut off
        column = QWidget()
        left = QVBoxLayout(column)
        left.setContentsMargins(0, 0, 0, 0)
        scroll = QScrollArea()
        scroll.setWidget(column)
        scroll.setWidgetResizable(True)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setFixedWidth(330)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        outer.addWidget(scroll, 0)
        left.addWidget(self._controls())
        self.state = WrapLabel("list the frames of a captured session, then calibrate")
        self.state.setWordWrap(True)
        left.addWidget(self.state)
        self.legend = WrapLabel("")
        self.legend.setWordWrap(True)
        left.addWidget(self.legend)
        left.addStretch(1)
        split = QSplitter(Qt.Orientation.Horizontal)
        self.image = _ClickImage()
        self.image.setText("no frame")
        self.image.clicked.connect(lambda x, y: self.safe(lambda: self.pick(x, y))())
        self.plot = PlotImage(drawer)
        split.addWidget(self.image)
        split.addWidget(self.plot)
        split.setSizes([560, 560])
        outer.addWidget(split, 1)
        self.plot.plot(empty_figure, title="Reflectance", hint="click the object in the frame",
                       xlabel="wavelength (nm)", ylabel="reflectance")

    def _controls(self) -> QGroupBox:
        """The frame, light, method and map controls with their buttons."""
        src = QGroupBox("Frame")
        f = QFormLayout(src)
        self.frames = QComboBox()
        self.frames.setMinimumContentsLength(14)
        self.list_button = refresh = QPushButton("List the session's frames")
        refresh.clicked.connect(self.safe(self.list_frames))
        self.frames.setToolTip("the session's object frames (pass / frame number)")
        self.frames.currentIndexChanged.connect(lambda i: self._frame_chosen())
        self.chart_frames = QComboBox()
        self.chart_frames.setMinimumContentsLength(14)
        self.chart_frames.setToolTip("the chart frame that calibrates the colours: by default the object frame's own "
                                     "pass's (the Camera tab lists the same ones)")
        self.light = QComboBox()
        self.light.addItems(["D65", "A", "D50", "F2"])
        self.light.setEditable(True)
        self.light.setToolTip("the light of the shot: D65, A, a CCT such as 3200K, or a CSV file")
        self.method = QComboBox()
        self.method.addItems(["wiener", "rootpoly", "more-basis", "paper"])
        for i, tip in enumerate((
                "Wiener: the statistically best linear estimate, from the camera's and the light's known spectra",
                "root-polynomial: a regression learned from the chart's 24 patches, robust to exposure",
                "more basis: a linear regression onto more spectral shapes than the paper's three",
                "paper: the original method, three spectral shapes and a 3 x 3 matrix (for comparison)")):
            self.method.setItemData(i, tip, Qt.ItemDataRole.ToolTipRole)
        self.load_button = QPushButton("Calibrate with the pass's chart")
        self.load_button.clicked.connect(self.safe(self.load))
        self.block = QSpinBox()
        self.block.setRange(2, 64)
        self.block.setValue(6)
        self.block.setSuffix(" px")
        self.min_confidence = QDoubleSpinBox()
        self.min_confidence.setRange(0.0, 1.0)
        self.min_confidence.setSingleStep(0.05)
        self.min_confidence.setValue(0.5)
        self.min_confidence.setToolTip("blocks whose best material is less likely than this are shown as "
                                       "'uncertain' rather than named")
        self.map_button = QPushButton("Material map")
        self.map_button.setToolTip("name the material of every block of the object in the frame")
        self.map_button.clicked.connect(self.safe(self.make_map))
        self.only_catalogued = QCheckBox("only the catalogued materials")
        self.only_catalogued.setToolTip("compare with the materials the Session tab's catalogue entry names "
                                        "(e.g. 'shibuichi, gold, urushi') instead of every known material")
        self.only_catalogued.toggled.connect(self._candidates_changed)
        self.candidates_label = WrapLabel("candidates: every known material")
        self.candidates_label.setWordWrap(True)
        self.list_button.setToolTip("list the open session's object frames and chart frames")
        self.load_button.setToolTip("calibrate the camera's colours with the chosen chart frame, then click the "
                                    "object to see its spectrum")
        self.method.setToolTip("how spectra are estimated from the camera colours: wiener (the default) is the "
                               "most robust; the others for comparison")
        self.block.setToolTip("side of the square blocks the material map names one material for")
        f.addRow(refresh)
        f.addRow("Object frame", self.frames)
        f.addRow("Chart frame", self.chart_frames)
        f.addRow("Light of the shot", self.light)
        f.addRow("Method", self.method)
        f.addRow(self.load_button)
        f.addRow("Map block", self.block)
        f.addRow("Min. confidence", self.min_confidence)
        f.addRow(self.only_catalogued)
        f.addRow(self.candidates_label)
        f.addRow(self.map_button)
        return src

    # ------------------------------------------------------------ sources
    def list_frames(self) -> None:
        from app.errors import UsageError
        from app.session import Session

        root = self.session_root()
        if root is None or not (root / "session.json").exists():
            raise UsageError("open a session with camera frames first (Session tab)")
        caps = Session.read(root)["captures"]
        frames = [k for k, r in caps.items() if r.get("kind") == "frame"]
        if not frames:
            raise UsageError(f"session {root} has no object frames (captured without the camera?)")
        from app.gui.camera_panel import chart_frame_label, session_chart_frames

        self.chart_frames.blockSignals(True)
        self.chart_frames.clear()
        for chart_id, number, _path in session_chart_frames(root):
            self.chart_frames.addItem(chart_frame_label(chart_id, number), chart_id)
        self.chart_frames.blockSignals(False)
        self.frames.clear()
        self.frames.addItems(frames)
        self._follow_pass()

    def _empty_plot(self, hint: str = "click the object in the frame") -> None:
        self.plot.plot(empty_figure, title="Reflectance", hint=hint, xlabel="wavelength (nm)", ylabel="reflectance")

    def _frame_chosen(self) -> None:
        """Another object frame chosen: its pass's chart, and nothing left of the previous frame's spectrum."""
        self._follow_pass()
        if self.last is not None:
            self.last = None
            self._empty_plot("calibrate the chosen frame, then click the object")

    def forget(self) -> None:
        """Another session was opened: nothing of the previous one stays on show."""
        self._requests += 1
        self._clicks += 1
        self.scene = self.last = self.map = None
        self.frames.clear()
        self.chart_frames.clear()
        self.legend.setText("")
        self.image.clear()
        self.image.image_size = None
        self.image.setText("no frame")
        self.state.setText("list the frames of a captured session, then calibrate")
        self._empty_plot()

    def _follow_pass(self) -> None:
        """Choose the chart frame of the object frame's pass (its first, for a swatch pass of several)."""
        pass_id = self.frames.currentText().split("/")[0]
        for i in range(self.chart_frames.count()):
            if str(self.chart_frames.itemData(i)).split("/")[0] == pass_id:
                self.chart_frames.setCurrentIndex(i)
                return

    def set_chart_corners(self, path: str, corners: str) -> None:
        """Corners of a chart frame marked by hand on the Camera tab: the calibration uses them for that frame."""
        self.manual_corners[str(path)] = corners

    def load(self) -> None:
        from app.errors import UsageError
        from app.session import Session

        root = self.session_root()
        cid = self.frames.currentText()
        if root is None or not cid:
            raise UsageError("list the session's frames and choose one")
        caps = Session.read(root)["captures"]
        chart_id = self.chart_frames.currentData()
        if chart_id is None or chart_id not in caps:
            raise UsageError(f"{cid}: the session has no chart frame, so the camera cannot be calibrated")
        frame, chart_path = root / caps[cid]["file"], root / caps[chart_id]["file"]
        light, method = self.light.currentText().strip(), self.method.currentText()
        corners = self.manual_corners.get(str(chart_path))
        chart_label = self.chart_frames.currentText() + (" (corners marked by hand)" if corners else "")
        self._chart_label = chart_label

        materials = self.candidate_names()

        def work(ctx: JobContext) -> SpectralScene:
            return analyse_spectra(frame, chart_path, light=light, method=method, corners=corners,
                                   materials=materials)

        self.state.setText(f"calibrating {cid} with the {chart_label}…")
        # the lane runs two jobs at once: only the latest request's result is shown (an older one finishing
        # later would show the previous frame, chart or candidates)
        self._requests += 1
        request = self._requests

        def loaded(scene: SpectralScene) -> None:
            if request == self._requests:
                self._loaded(scene)

        def failed(text: str, exc: Any) -> None:
            if request == self._requests:
                self.state.setText(f"failed: {text}")
                self.error.emit(text)

        self.lane.run(work, "spectra", succeeded=loaded, failed=failed)

    def candidate_names(self) -> list[str] | None:
        """The candidates: the catalogued materials when asked for (None: every known material)."""
        from app.errors import UsageError

        if not self.only_catalogued.isChecked():
            self.candidates_label.setText("candidates: every known material")
            return None
        text = self.catalogue().strip()
        names, unmatched = catalogued_candidates(text)
        if len(names) < 2:
            self.only_catalogued.setChecked(False)
            raise UsageError(f"the catalogue entry {text!r} names {len(names)} known material(s); the comparison "
                             "needs two or more: fill in 'Materials (as catalogued)' on the Session tab "
                             "(e.g. shibuichi, gold, urushi)")
        self.candidates_label.setText("candidates: " + ", ".join(names)
                                      + (f" (not known: {', '.join(unmatched)})" if unmatched else ""))
        return names

    def _candidates_changed(self, on: bool) -> None:
        try:
            self.candidate_names()
        except Exception as exc:  # noqa: BLE001 - shown in the window
            self.error.emit(f"spectra: {exc}")
            return
        if self.scene is not None:
            self.safe(self.load)()              # the same frame, compared with the new candidates

    def _loaded(self, scene: SpectralScene) -> None:
        self.scene = scene
        self.map = None
        self.last = None
        self.legend.setText("")
        self._empty_plot()
        self.image.show_rgb(scene.preview)
        self.state.setText(f"{scene.frame.name}: {scene.fit.method} estimate calibrated with the "
                           f"{getattr(self, '_chart_label', 'chart frame')} on {scene.usable_patches} "
                           f"chart patches under {scene.light} (error on the chart {scene.method_error:.3f}). Click the "
                           "object to see its spectrum.")
        self.log.emit(self.state.text())

    # ------------------------------------------------------------ click and map
    def pick(self, x: int, y: int) -> None:
        from app.errors import UsageError

        if self.scene is None:
            raise UsageError("calibrate a frame first")
        scene = self.scene

        def work(ctx: JobContext) -> dict[str, Any]:
            return spectrum_at(scene, x, y)

        self._clicks += 1
        click = self._clicks

        def picked(res: dict[str, Any]) -> None:
            if click == self._clicks and scene is self.scene:        # the latest click, on the frame shown
                self._picked(res)

        def refused(text: str, exc: Any) -> None:
            if click == self._clicks:
                self.state.setText(f"not measured: {text}")
                self.error.emit(f"spectrum: {text}")

        self.lane.run(work, "spectrum", succeeded=picked, failed=refused)

    def _picked(self, res: dict[str, Any]) -> None:
        self.last = res
        self._show_frame()
        ident = res["identification"]
        self.plot.plot(spectrum_figure, wavelengths=res["wavelengths"], mean=res["mean"],
                       uncertainty=res["uncertainty"], model=res["model"], model_name=res["model_name"],
                       pixels=res["pixels"],
                       title=f"({res['x']}, {res['y']}): {answer_title(ident)}")
        self.state.setText(f"pixel ({res['x']}, {res['y']}), {res['pixels']} pixels: "
                           f"{answer_text(ident, res.get('colour_error', 0.0))}")
        self.analysed.emit(res)

    def make_map(self) -> None:
        from app.errors import UsageError

        if self.scene is None:
            raise UsageError("calibrate a frame first")
        scene, block, confidence = self.scene, int(self.block.value()), float(self.min_confidence.value())

        def work(ctx: JobContext) -> tuple[np.ndarray, dict[int, str]]:
            return material_map(scene, block, min_confidence=confidence)

        self.state.setText("identifying the material of every block…")
        self.lane.run(work, "material map", succeeded=self._mapped,
                      failed=lambda text, exc: self.error.emit(f"material map: {text}"))

    def _show_frame(self) -> None:
        """The frame, the material map over it (if made) and a cross at the clicked point."""
        img = self.scene.preview.copy()
        if self.map is not None:
            labels, names = self.map
            colours = _map_colours(names)[labels]
            alpha = np.where(labels > 0, 0.45, 0.0)[..., None]
            img = (img.astype(np.float32) * (1 - alpha) + colours * alpha).astype(np.uint8)
        if self.last is not None:
            x, y = self.last["x"], self.last["y"]
            h, w = img.shape[:2]
            arm = max(3, min(h, w) // 40)
            img[max(y - arm, 0):y + arm + 1, x] = (255, 40, 40)
            img[y, max(x - arm, 0):x + arm + 1] = (255, 40, 40)
        self.image.show_rgb(img)

    def _mapped(self, result: tuple[np.ndarray, dict[int, str]]) -> None:
        self.map = result
        labels, names = result
        palette = _map_colours(names)
        self._show_frame()
        confidence = self.min_confidence.value()
        self.legend.setText("<br>".join(
            f"<span style='background:rgb({c[0]},{c[1]},{c[2]})'>&nbsp;&nbsp;&nbsp;</span> "
            + (f"{n} (confidence below {confidence:.2f})" if n == UNCERTAIN else n)
            for i, n in sorted(names.items()) for c in [palette[i]]))
        materials = sum(1 for n in names.values() if n != UNCERTAIN)
        uncertain = [i for i, n in names.items() if n == UNCERTAIN]
        judged = labels[labels > 0]
        share = float(np.isin(judged, uncertain).mean()) if judged.size else 0.0
        cov = map_coverage(self.scene, labels)
        whole = max(cov["object"], 1)
        self.coverage = cov
        self.state.setText(f"material map: judged {100 * cov['judged'] / whole:.0f}% of the object "
                           f"({cov['judged']:,} of {cov['object']:,} pixels); left out: "
                           f"{100 * cov['dark'] / whole:.0f}% too dark, {100 * cov['clipped'] / whole:.0f}% clipped, "
                           f"{100 * cov['sparse'] / whole:.0f}% in blocks less than half usable. "
                           f"{materials} material{'' if materials == 1 else 's'} over blocks of {self.block.value()} px, "
                           f"{100 * share:.0f}% of the judged area uncertain")
        self.map_ready.emit()
