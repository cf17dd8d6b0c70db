"""Preview panel: the renderer's image of the session's mesh with a chosen material, under a chosen light.

When the session's materials were measured on the mesh (``kogei fit-materials``, the batch's
``materials`` step), the material list starts with "measured (on the mesh)": the object with its
regions' fitted materials (``products/object-mesh.ply``).  A click on the object then shows the
clicked region's observations against its fitted model (:func:`app.workflows.object_materials.
region_observations`) under the image.

A thin shell over :func:`app.workflows.scene_build.build_job` and
:func:`render.renderer.render` (what ``kogei render`` runs).  Dragging the
image orbits the camera about the mesh's centre; while dragging a small
``draft`` image is rendered (about 1/4 of the size), and once the mouse has
been still for :attr:`PreviewPanel.settle_ms` the image is refined at full
size with the chosen preset.  Renders run on a worker thread; only the latest
request is rendered (a request made while one renders replaces any waiting
one), so dragging never queues up stale work.  The illuminant is D65, A or a
custom correlated colour temperature (``3200K`` style, as ``--illuminant``).

"Adapt to display white" (on by default, as ``kogei render``) adapts the image from the light's white to
the display's D65 white (CAT02), as the eye adapts to a room: a white surface looks white under any light, so
D65 and A look nearly alike.  Off, the XYZ go to sRGB unadapted (:func:`display_srgb8`), as a camera balanced
for daylight would show them: under A (tungsten) the object looks warm.

Examples
--------
>>> import numpy as np
>>> eye = orbit_eye(np.zeros(3), 100.0, azimuth_deg=0.0, elevation_deg=0.0)
>>> np.round(eye, 6).tolist()
[100.0, 0.0, 0.0]
>>> light_vector(90.0, 0.0)
(0.0, 1.0, 0.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QPoint, Qt, QTimer, Signal
from PySide6.QtGui import QPixmap
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QFrame,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QScrollArea,
    QSizePolicy,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from app.gui.session_panel import rgb_to_qimage
from app.gui.widgets import Panel
from app.gui.workers import JobContext, Lane, ProcessJob, WorkerProcess

__all__ = ["PreviewPanel", "orbit_eye", "light_vector", "render_view", "click_ray", "display_srgb8", "MEASURED",
           "LIGHTINGS"]

#: The Preview tab's lighting choices.
LIGHTINGS = ("directional light", "daylight sky (sun at the light's direction)", "light probe / HDR map")

#: The material choice that renders the regions' measured materials.
MEASURED = "measured (on the mesh)"


def orbit_eye(center: np.ndarray, distance: float, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Camera position on a sphere about ``center`` (mm; azimuth from +x toward +y, elevation above the table)."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.asarray(center, float) + distance * np.array([math.cos(el) * math.cos(az),
                                                            math.cos(el) * math.sin(az), math.sin(el)])


def light_vector(azimuth_deg: float, elevation_deg: float) -> tuple[float, float, float]:
    """Direction toward a directional light (unit vector, rounded to 12 digits)."""
    v = orbit_eye(np.zeros(3), 1.0, azimuth_deg, elevation_deg)
    return tuple(float(round(c, 12)) + 0.0 for c in v)


def click_ray(view: dict[str, Any], x_px: float, y_px: float) -> tuple[np.ndarray, np.ndarray]:
    """The ray (origin, unit direction; mesh frame, mm) through image pixel ``(x_px, y_px)`` of a rendered view.

    ``view`` holds the render's camera (``eye``, ``target``, ``up``, ``fov_deg`` vertical) and its
    ``srgb8`` image (for the size); pixel (0, 0) is the top-left pixel's corner.

    Examples
    --------
    >>> v = {"eye": np.array([0.0, -10, 0]), "target": np.zeros(3), "up": np.array([0.0, 0, 1]), "fov_deg": 40.0,
    ...      "srgb8": np.zeros((30, 40, 3), np.uint8)}
    >>> o, d = click_ray(v, 20.0, 15.0)
    >>> np.round(d, 6).tolist()
    [0.0, 1.0, 0.0]
    """
    h, w = view["srgb8"].shape[:2]
    eye, target = np.asarray(view["eye"], float), np.asarray(view["target"], float)
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, np.asarray(view["up"], float))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    half = math.tan(math.radians(float(view["fov_deg"])) / 2)
    sx = (2 * x_px / w - 1) * half * w / h
    sy = (1 - 2 * y_px / h) * half
    d = fwd + sx * right + sy * up
    return eye, d / np.linalg.norm(d)


def display_srgb8(xyz: np.ndarray, mask: np.ndarray, white: np.ndarray, *, adapt: bool,
                  background_black: bool = True) -> np.ndarray:
    """8-bit sRGB of a render's XYZ, adapted from the light's ``white`` to the display's D65 white or not.

    ``adapt`` False shows the light's own colour (the XYZ taken as they are, sRGB's white being D65); pixels no
    object covers stay black when ``background_black``.

    Examples
    --------
    >>> from processing.spectral.display import white_xyz
    >>> from processing.spectral.spectra import light_spectrum
    >>> a = white_xyz(light_spectrum("A"))[None, None, :]
    >>> one = np.ones((1, 1))
    >>> display_srgb8(a, one, a[0, 0], adapt=True).tolist(), display_srgb8(a, one, a[0, 0], adapt=False).tolist()
    ([[[255, 255, 255]]], [[[255, 234, 133]]])
    """
    from processing.spectral.display import xyz_to_srgb8

    xyz = np.asarray(xyz)
    if not background_black:
        return xyz_to_srgb8(xyz, white, adapt=adapt)
    out = np.zeros(xyz.shape[:-1] + (3,), np.uint8)
    covered = np.asarray(mask) > 0
    if covered.any():
        out[covered] = xyz_to_srgb8(xyz[covered], white, adapt=adapt)
    return out


def _region_plot_data(session: str, origin: np.ndarray, direction: np.ndarray) -> dict[str, Any] | None:
    """The clicked region's observations against its model, or None when the click missed the object."""
    from app.workflows.object_materials import face_region_at, region_observations

    region = face_region_at(session, origin, direction)
    if region is None:
        return None
    if region < 0:
        return {"region": {"index": -1, "material": "not measured", "confidence": 0.0}}
    return region_observations(session, region)


class _SameGeometry:
    """The drafts of an orbit re-render one mesh: keep its ray tracer between renders of this process.

    Every render reads the mesh file again (a new :class:`render.meshio.Mesh`); a mesh equal to the
    previous render's (vertices, triangles and normals) is swapped for that one, so the
    :class:`render.renderer.GeometryCache` -- keyed on the mesh objects -- serves its tracer instead of
    building it again.
    """

    def __init__(self) -> None:
        import threading

        from render.renderer import GeometryCache

        self.cache = GeometryCache()
        self._lock = threading.Lock()
        self._meshes: tuple = ()

    def scene(self, scene: Any) -> Any:
        """``scene`` with each mesh equal to the last render's replaced by that mesh object."""
        import dataclasses

        with self._lock:
            objects = []
            for i, obj in enumerate(scene.objects):
                prev = self._meshes[i] if i < len(self._meshes) else None
                if prev is not None and prev is not obj.mesh and _equal_meshes(prev, obj.mesh):
                    obj = dataclasses.replace(obj, mesh=prev)
                objects.append(obj)
            self._meshes = tuple(o.mesh for o in objects)
        return dataclasses.replace(scene, objects=objects)


def _equal_meshes(a: Any, b: Any) -> bool:
    """True when two meshes have the same vertices, triangles and vertex normals."""
    return all(x.shape == y.shape and np.array_equal(x, y) for x, y in
               ((a.vertices, b.vertices), (a.triangles, b.triangles), (a.vertex_normals, b.vertex_normals)))


#: The drafts' geometry, kept between the renders of this process.
_GEOMETRY = _SameGeometry()


def _render_final(args: dict[str, Any], message: Callable[[str], None]) -> dict[str, Any]:
    """:func:`render_view` in a worker process (:class:`app.gui.workers.ProcessJob` passes ``message``)."""
    return render_view(**args)


def render_view(mesh: str, material: str, illuminant: str, light: tuple[float, float, float],
                azimuth_deg: float, elevation_deg: float, size: tuple[int, int], preset: str,
                bounds: tuple[np.ndarray, np.ndarray], environment: str | None = None,
                adapt_white: bool = True) -> dict[str, Any]:
    """Render ``mesh`` from the orbit camera.

    ``environment`` (the ``kogei render --environment`` text: a ``.exr`` / ``.hdr`` file or
    ``sky:...``) lights the mesh instead of the directional ``light``.  ``adapt_white`` False shows
    the light's own colour (:func:`display_srgb8`) instead of adapting it to the display's white.

    Returns
    -------
    dict
        ``srgb8`` ``(H, W, 3)`` uint8, ``mask`` ``(H, W)`` object coverage,
        ``seconds`` of rendering, the camera: ``eye``, ``target``, ``up``
        (mm), ``fov_deg`` (vertical), and ``geometry_reused``: True when the
        previous render in this process had the same mesh and its ray tracer
        served again.
    """
    import time

    from app.workflows.scene_build import build_job
    from app.workflows.scene_spec import CameraSpec, LightSpec, ObjectSpec, SceneSpec, parse_environment
    from render.renderer import render

    lo, hi = bounds
    center = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2 or 1.0
    fov = 35.0
    distance = radius / math.sin(math.radians(fov) / 2) * 1.05
    eye = orbit_eye(center, distance, azimuth_deg, elevation_deg)
    up = (0.0, 0.0, 1.0) if abs(elevation_deg) < 89.0 else (0.0, 1.0, 0.0)
    env = None if environment is None else parse_environment(environment, "environment")
    spec = SceneSpec(objects=[ObjectSpec(mesh=Path(mesh), material=material)],
                     lights=[] if env is not None else [LightSpec("directional", light)], illuminant=illuminant,
                     size=size, preset=preset, environment=env,
                     camera=CameraSpec(eye=tuple(eye.tolist()), target=tuple(center.tolist()), up=up, fov_deg=fov))
    job = build_job(spec)
    t = time.perf_counter()
    result = render(_GEOMETRY.scene(job.scene), job.camera, job.settings, geometry_cache=_GEOMETRY.cache)
    srgb8 = result.srgb8 if adapt_white else display_srgb8(result.xyz, result.mask, result.white, adapt=False,
                                                           background_black=not result.sky_visible)
    return {"srgb8": srgb8, "mask": result.mask, "seconds": time.perf_counter() - t, "eye": eye,
            "geometry_reused": bool(result.stats["geometry_reused"]),
            "target": center, "up": np.asarray(up, float), "fov_deg": fov}


class _ImageView(QLabel):
    """The rendered image; reports drags as orbit deltas."""

    dragged = Signal(float, float)
    released = Signal()
    clicked = Signal(float, float)

    def __init__(self) -> None:
        super().__init__()
        self.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.setMinimumSize(320, 240)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setStyleSheet("background:#202020; color:#ddd;")
        self._last: QPoint | None = None

    def mousePressEvent(self, e: Any) -> None:  # noqa: N802
        self._last = e.position().toPoint()
        self._moved = False

    def mouseMoveEvent(self, e: Any) -> None:  # noqa: N802
        if self._last is None:
            return
        p = e.position().toPoint()
        d = p - self._last
        if abs(d.x()) + abs(d.y()) < 2 and not self._moved:
            return
        self._moved = True
        self._last = p
        self.dragged.emit(float(d.x()), float(d.y()))

    def mouseReleaseEvent(self, e: Any) -> None:  # noqa: N802
        moved, self._last = getattr(self, "_moved", True), None
        if moved:
            self.released.emit()
        else:
            p = e.position()
            self.clicked.emit(float(p.x()), float(p.y()))

    def image_point(self, x: float, y: float, size: tuple[int, int]) -> tuple[float, float] | None:
        """Widget point -> pixel of the shown image of ``size`` (width, height), or None outside it."""
        w, h = size
        scale = min(self.width() / w, self.height() / h)
        x0, y0 = (self.width() - w * scale) / 2, (self.height() - h * scale) / 2
        u, v = (x - x0) / scale, (y - y0) / scale
        return (u, v) if 0 <= u < w and 0 <= v < h else None


class PreviewPanel(Panel):
    """See the module docstring."""

    rendered = Signal(str)           # 'draft' or 'final'

    #: Stillness (ms) after which the image is refined.
    settle_ms = 350

    def __init__(self, lane: Lane, session_root: Callable[[], Path | None], drawer: Any = None,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lane = lane
        self.session_root = session_root
        self.mesh_path: str | None = None
        self.object_mesh: str | None = None
        self.bounds: tuple[np.ndarray, np.ndarray] | None = None
        self.image: np.ndarray | None = None
        self.last: dict[str, Any] | None = None
        self.last_kind = ""
        self._busy = False
        self._waiting: tuple[str, dict[str, Any]] | None = None
        #: The process the full-size renders run in, kept between them (its imports and the mesh's ray tracer).
        self.render_worker = WorkerProcess()
        outer = QHBoxLayout(self)
        left = QVBoxLayout()
        outer.addLayout(left, 1)
        self.view = _ImageView()
        self.view.setText("no mesh yet: process the session, or open a mesh")
        self.view.dragged.connect(self._drag)
        self.view.released.connect(self._settle_later)
        self.view.clicked.connect(self.safe(self._clicked))
        left.addWidget(self.view, 3)
        self.region_plot = None
        if drawer is not None:
            from app.gui.figures import empty_figure
            from app.gui.plots import PlotImage

            self.region_plot = PlotImage(drawer)
            self.region_plot.setMinimumHeight(150)
            self.region_plot.plot(empty_figure, title="Region observations",
                                  hint="render the measured object and click a point of it")
            left.addWidget(self.region_plot, 2)

        column = QWidget()                      # the controls scroll in a short window (700 px high)
        side = QVBoxLayout(column)
        side.setContentsMargins(0, 0, 0, 0)
        scroll = QScrollArea()
        scroll.setWidget(column)
        scroll.setWidgetResizable(True)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        outer.addWidget(scroll, 0)
        g = QGroupBox("Scene")
        f = QFormLayout(g)
        self.mesh_label = QLabel("–")
        self.mesh_label.setWordWrap(True)
        open_mesh = QPushButton("Open mesh…")
        open_mesh.setToolTip("render a mesh file (PLY, OBJ, ...) instead of the session's")
        open_mesh.clicked.connect(self.safe(self._open_mesh))
        use_session = QPushButton("Use the session's mesh")
        use_session.setToolTip("render the open session's mesh (after processing), with its measured materials "
                               "if any")
        use_session.clicked.connect(self.safe(self.mesh_changed))
        f.addRow("Mesh", self.mesh_label)
        f.addRow(open_mesh)
        f.addRow(use_session)
        from processing.materials.presets import list_materials

        self.material = QComboBox()
        self.material.addItems([MEASURED, *list_materials()])
        self.material.model().item(0).setEnabled(False)
        self.material.setCurrentText("nami-shibuichi")
        self.illuminant = QComboBox()
        self.illuminant.addItems(["D65", "A", "custom CCT"])
        self.cct = QSpinBox()
        self.cct.setRange(1000, 25000)
        self.cct.setSingleStep(100)
        self.cct.setValue(3200)
        self.cct.setSuffix(" K")
        self.preset = QComboBox()
        self.preset.addItems(["draft", "standard", "reference"])
        self.preset.setCurrentText("standard")
        self.adapt = QCheckBox("Adapt to display white")
        self.adapt.setChecked(True)
        self.adapt.setToolTip("on: the image is adapted from the light's white to the display's (CAT02), as the "
                              "eye adapts to a room's light: white looks white under any illuminant, so D65 and A "
                              "look nearly alike. Off: the display shows the light's own colour, as a camera "
                              "balanced for daylight would: under A (tungsten) the object looks warm")
        self.size = QComboBox()
        self.size.addItems(["480x360", "640x480", "800x600", "160x120"])
        self.material.setToolTip("the material to render the mesh with; 'measured' uses the materials measured "
                                 "on the mesh")
        self.illuminant.setToolTip("the light's spectrum: daylight (D65), incandescent (A) or a colour "
                                   "temperature")
        self.cct.setToolTip("the colour temperature of the custom light (kelvin)")
        self.preset.setToolTip("render quality once the view stops moving: draft, standard or reference")
        self.size.setToolTip("the rendered image's size in pixels")
        f.addRow("Material", self.material)
        f.addRow("Illuminant", self.illuminant)
        f.addRow("CCT", self.cct)
        f.addRow(self.adapt)
        f.addRow("Preset (when still)", self.preset)
        f.addRow("Image size", self.size)
        side.addWidget(g)
        lg = QGroupBox("Light and view")
        lf = QFormLayout(lg)
        self.lighting = QComboBox()
        self.lighting.addItems(LIGHTINGS)
        self.lighting.setToolTip("what lights the object: one directional light; an outdoor daylight sky whose sun "
                                 "stands at the light's azimuth and elevation; or a measured light probe "
                                 "(kogei probe) or another HDR environment map (.exr / .hdr)")
        self.probe_path = QLabel("no probe chosen")
        self.probe_path.setWordWrap(True)
        self.probe_button = QPushButton("Choose probe…")
        self.probe_button.setToolTip("an environment map: the .exr kogei probe writes, or a .hdr / .exr from "
                                     "elsewhere (read as linear sRGB)")
        self.probe_button.clicked.connect(self.safe(self._choose_probe))
        self.probe_file: str | None = None
        lf.addRow("Lighting", self.lighting)
        lf.addRow(self.probe_button, self.probe_path)
        self.light_az = QDoubleSpinBox()
        self.light_el = QDoubleSpinBox()
        self.azimuth = QDoubleSpinBox()
        self.elevation = QDoubleSpinBox()
        for sb, lo, hi, val in ((self.light_az, -360, 360, 200.0), (self.light_el, -89, 89, 50.0),
                                (self.azimuth, -3600, 3600, -90.0), (self.elevation, -89, 89, 15.0)):
            sb.setRange(lo, hi)
            sb.setValue(val)
            sb.setSuffix(" °")
            sb.setKeyboardTracking(False)
        for sb, tip in ((self.light_az, "the light's direction around the object (degrees)"),
                        (self.light_el, "the light's height above the horizon (degrees)"),
                        (self.azimuth, "the view's direction around the object (degrees; or drag the image)"),
                        (self.elevation, "the view's height above the horizon (degrees; or drag the image)")):
            sb.setToolTip(tip)
        lf.addRow("Light azimuth", self.light_az)
        lf.addRow("Light elevation", self.light_el)
        lf.addRow("View azimuth (drag)", self.azimuth)
        lf.addRow("View elevation (drag)", self.elevation)
        side.addWidget(lg)
        self.render_button = QPushButton("Render")
        self.render_button.setToolTip("render now at the chosen quality")
        self.render_button.clicked.connect(self.safe(lambda: self.request("final")))
        self.save_button = QPushButton("Save image…")
        self.save_button.setToolTip("save the rendered image as a PNG file")
        self.save_button.clicked.connect(self.safe(self._save))
        side.addWidget(self.render_button)
        side.addWidget(self.save_button)
        self.info = QLabel("")
        self.info.setWordWrap(True)
        side.addWidget(self.info)
        side.addStretch(1)
        scroll.setMinimumWidth(column.sizeHint().width() + 24)     # no horizontal scrolling
        self.cct.setEnabled(False)
        self.illuminant.currentTextChanged.connect(lambda t: self.cct.setEnabled(t == "custom CCT"))
        for w in (self.material, self.illuminant, self.preset, self.size, self.lighting):
            w.currentTextChanged.connect(lambda _: self._settle_later())
        self.lighting.currentTextChanged.connect(self._lighting_changed)
        self._lighting_changed(self.lighting.currentText())
        for w in (self.cct, self.light_az, self.light_el, self.azimuth, self.elevation):
            w.valueChanged.connect(lambda _: self._settle_later())
        self.adapt.toggled.connect(lambda _: self._settle_later())
        self._settle = QTimer(self)
        self._settle.setSingleShot(True)
        self._settle.setInterval(self.settle_ms)
        self._settle.timeout.connect(lambda: self.request("final"))

    # ------------------------------------------------------------ mesh
    def mesh_changed(self) -> None:
        """Use the open session's ``products/mesh.ply`` (after processing), and its measured materials if any."""
        from app.errors import UsageError

        root = self.session_root()
        mesh = None if root is None else root / "products" / "mesh.ply"
        if mesh is None or not mesh.exists():
            raise UsageError("the session has no mesh yet: process it on the Processing tab")
        measured = root / "products" / "object-mesh.ply"
        self.object_mesh = str(measured) if measured.exists() else None
        self.material.model().item(0).setEnabled(self.object_mesh is not None)
        if self.object_mesh is not None:
            self.material.blockSignals(True)
            self.material.setCurrentText(MEASURED)
            self.material.blockSignals(False)
        elif self.material.currentText() == MEASURED:
            self.material.setCurrentText("nami-shibuichi")
        self.set_mesh(str(mesh))

    def _open_mesh(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Mesh", "", "Meshes (*.ply *.obj *.stl *.glb *.gltf *.off)")
        if path:
            self.set_mesh(path)

    def set_mesh(self, path: str) -> None:
        """Use the mesh file ``path`` (read on a worker thread), then render it."""
        def work(ctx: JobContext) -> tuple[np.ndarray, np.ndarray, int]:
            from render.meshio import load_mesh

            mesh = load_mesh(path)
            v = np.asarray(mesh.vertices, float)
            return v.min(axis=0), v.max(axis=0), len(mesh.triangles)

        def loaded(result: tuple[np.ndarray, np.ndarray, int]) -> None:
            lo, hi, n = result
            self.bounds = (lo, hi)
            self.mesh_path = path
            self.mesh_label.setText(f"{path}\n{n} triangles")
            self.request("final")

        self.mesh_label.setText(f"reading {path}…")
        self.lane.run(work, "read mesh", succeeded=loaded,
                      failed=lambda text, exc: self.error.emit(f"preview: {path}: {text}"))

    # ------------------------------------------------------------ light
    def _lighting_changed(self, text: str) -> None:
        probe = text == LIGHTINGS[2]
        self.probe_button.setEnabled(probe)
        self.probe_path.setEnabled(probe)
        self.light_az.setEnabled(not probe)          # the directional light or the sky's sun; a probe is measured
        self.light_el.setEnabled(not probe)
        if probe and self.probe_file is None:
            root = self.session_root()
            kept = None if root is None else root / "products" / "probe.exr"
            if kept is not None and kept.is_file():
                self.set_probe(str(kept))

    def _choose_probe(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Light probe", "", "Environment maps (*.exr *.hdr)")
        if path:
            self.set_probe(path)

    def set_probe(self, path: str) -> None:
        """Light the preview with the environment map ``path`` (a ``kogei probe`` .exr or a .hdr / .exr)."""
        self.probe_file = path
        self.probe_path.setText(path)
        self.lighting.setCurrentText(LIGHTINGS[2])
        self._settle_later()

    def environment_text(self) -> str | None:
        """The ``--environment`` text of the chosen lighting (None: the directional light)."""
        from app.errors import UsageError

        text = self.lighting.currentText()
        if text == LIGHTINGS[1]:
            return f"sky:sun_elevation={max(self.light_el.value(), 0.0):g},sun_azimuth={self.light_az.value():g}"
        if text == LIGHTINGS[2]:
            if self.probe_file is None:
                raise UsageError("no light probe chosen: press 'Choose probe…' (a kogei probe .exr or a .hdr)")
            return self.probe_file
        return None

    # ------------------------------------------------------------ rendering
    def illuminant_name(self) -> str:
        text = self.illuminant.currentText()
        return f"{self.cct.value()}K" if text == "custom CCT" else text

    def _size(self) -> tuple[int, int]:
        w, h = (int(x) for x in self.size.currentText().split("x"))
        return w, h

    def _drag(self, dx: float, dy: float) -> None:
        if self.mesh_path is None:
            return
        self.azimuth.blockSignals(True)
        self.elevation.blockSignals(True)
        self.azimuth.setValue(self.azimuth.value() - 0.5 * dx)
        self.elevation.setValue(max(-89.0, min(89.0, self.elevation.value() + 0.5 * dy)))
        self.azimuth.blockSignals(False)
        self.elevation.blockSignals(False)
        self._settle.stop()
        self.request("draft")

    def _settle_later(self) -> None:
        if self.mesh_path is not None:
            self._settle.start()

    def request(self, kind: str) -> None:
        """Ask for a ``draft`` (small, fast) or ``final`` image of the current view."""
        from app.errors import UsageError

        if self.mesh_path is None or self.bounds is None:
            return
        w, h = self._size()
        if kind == "draft":
            size, preset = (max(64, w // 4), max(48, h // 4)), "draft"
        else:
            size, preset = (w, h), self.preset.currentText()
        measured = self.material.currentText() == MEASURED and self.object_mesh is not None
        args = {"mesh": self.object_mesh if measured else self.mesh_path,
                "material": "nami-shibuichi" if measured else self.material.currentText(),
                "illuminant": self.illuminant_name(),
                "light": light_vector(self.light_az.value(), self.light_el.value()),
                "azimuth_deg": self.azimuth.value(), "elevation_deg": self.elevation.value(),
                "size": size, "preset": preset, "bounds": self.bounds, "adapt_white": self.adapt.isChecked()}
        try:
            args["environment"] = self.environment_text()
        except UsageError as exc:
            self.info.setText(str(exc))
            return
        self._waiting = (kind, args)
        self._next()

    def _next(self) -> None:
        if self._busy or self._waiting is None:
            return
        kind, args = self._waiting
        self._waiting = None
        self._busy = True
        self.info.setText(f"rendering {kind} {args['size'][0]}x{args['size'][1]} ({args['preset']})…")

        if kind == "final":
            # Open3D's cast_rays holds the interpreter lock for a whole call (45 ms for 480 x 360 rays on an
            # idle core, over 100 ms on a busy one), so a full-size render in a thread stalls the event loop:
            # it runs in a worker process; drafts (a sixteenth of the rays) stay on the lane for the orbit.  The
            # process is kept for the next final render: starting one (Python, Qt's bindings, Open3D, colour-science)
            # took longer than the render itself
            job = ProcessJob(_render_final, args, parent=self, worker=self.render_worker)
            job.succeeded.connect(lambda out: self._shown((kind, out, args)))
            job.failed.connect(self._failed)
            job.finished.connect(self._done)
            self._process_job = job.start()
            return

        def work(ctx: JobContext) -> tuple[str, dict[str, Any], dict[str, Any]]:
            return kind, render_view(**args), args

        self.lane.run(work, f"render {kind}", succeeded=self._shown, failed=self._failed, finished=self._done)

    def _shown(self, result: tuple[str, dict[str, Any], dict[str, Any]]) -> None:
        kind, out, args = result
        img, secs = out["srgb8"], out["seconds"]
        self.image = img
        self.last = out
        self.last_kind = kind
        pix = QPixmap.fromImage(rgb_to_qimage(img))
        target = self.view.size()
        self.view.setPixmap(pix.scaled(target, Qt.AspectRatioMode.KeepAspectRatio,
                                       Qt.TransformationMode.SmoothTransformation))
        shown = MEASURED if args["mesh"] == self.object_mesh else args["material"]
        env = args.get("environment")
        light = (args["illuminant"] if env is None else "the daylight sky" if env.startswith("sky:")
                 else f"the map {Path(env.split(':rotate=')[0].split(':intensity=')[0]).name}")
        adapted = "" if args.get("adapt_white", True) else " (the light's colour, not adapted)"
        self.info.setText(f"{kind}: {img.shape[1]}x{img.shape[0]}, {args['preset']}, {shown} under {light}"
                          f"{adapted}, {secs:.2f} s")
        self.rendered.emit(kind)

    def _failed(self, text: str, exc: Any) -> None:
        self.info.setText(f"render failed: {text}")
        self.error.emit(f"preview: {text}")

    def _done(self) -> None:
        self._busy = False
        self._next()

    def _clicked(self, x: float, y: float) -> None:
        """A click on the measured object: plot the clicked region's observations against its model."""
        if self.last is None or self.region_plot is None:
            return
        img = self.last["srgb8"]
        point = self.view.image_point(x, y, (img.shape[1], img.shape[0]))
        root = self.session_root()
        if point is None or root is None or self.object_mesh is None or self.material.currentText() != MEASURED:
            self.info.setText("click the measured object (material: measured (on the mesh)) to see its region's "
                              "observations")
            return
        origin, direction = click_ray(self.last, *point)

        def work(ctx: JobContext) -> dict[str, Any] | None:
            return _region_plot_data(str(root), origin, direction)

        self.info.setText("reading the clicked region's observations…")
        self.lane.run(work, "region observations", succeeded=self._region_shown,
                      failed=lambda text, exc: self.error.emit(f"preview: region: {text}"))

    def _region_shown(self, data: dict[str, Any] | None) -> None:
        from app.gui.figures import empty_figure, region_fit_figure

        if data is None:
            self.info.setText("the click missed the object")
            return
        from app.workflows.object_materials import answer_text

        reg = data["region"]
        title = f"region {reg['index']}: {answer_text(reg)}"
        if "observed" not in data or len(data["observed"]) == 0:
            self.region_plot.plot(empty_figure, title=title, hint=reg.get("reason") or "no observation to show")
        else:
            self.region_plot.plot(region_fit_figure, half_angle_deg=data["half_angle_deg"],
                                  observed=data["observed"], predicted=data["predicted"], title=title)
        self.info.setText(title)

    def _save(self) -> None:
        """Ask where, then write the shown image as PNG on the preview's lane (a disk's wait stays off the window)."""
        from app.errors import UsageError

        if self.image is None:
            raise UsageError("render an image first")
        path, _ = QFileDialog.getSaveFileName(self, "Save image", "preview.png", "PNG (*.png)")
        if not path:
            return
        image = self.image.copy()                        # the next render replaces the panel's image

        def work(ctx: Any) -> str:
            from render.image_io import write_png

            return str(write_png(path, image))

        self.lane.run(work, "save image", succeeded=lambda written: self.log.emit(f"preview saved to {written}"),
                      failed=lambda text, exc: self.error.emit(f"preview: not saved to {path}: {text}"))
