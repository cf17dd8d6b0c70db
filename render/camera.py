"""Pinhole camera: primary ray generation with stratified sub-pixel samples.

The camera looks from ``eye`` toward ``target``; ``fov_deg`` is the vertical
field of view.  Pixel (column x, row y) covers the square [x, x+1) x [y, y+1)
of the image plane, row 0 at the top.  With one sample per pixel the ray
goes through the pixel centre; with ``s > 1`` samples the pixel is divided
into ``k = ceil(sqrt(s))`` columns and ``ceil(s / k)`` rows of strata and one
sample is placed in each of the first ``s`` strata: either jittered at
random within it (stratified sampling, Cook 1986, "Stochastic sampling in
computer graphics", ACM TOG 5(1)), which trades aliasing for noise, or on a
rotated ordered grid (for four samples the rotated-grid supersampling
pattern, Akenine-Moeller et al., "Real-Time Rendering", 4th ed., section
5.4.2), deterministic, with no two samples sharing a pixel row or column.

References
----------
Cook, R. L. (1986), "Stochastic sampling in computer graphics", ACM
Transactions on Graphics 5(1), 51-72 (DOI not verified).
Akenine-Moeller, T., Haines, E., Hoffman, N. et al. (2018), "Real-Time
Rendering", 4th ed., CRC Press, section 5.4.2 (a book, no DOI).

Examples
--------
>>> cam = Camera(eye=(0, -5, 0), target=(0, 0, 0), up=(0, 0, 1), fov_deg=40, width=4, height=3)
>>> rays = cam.rays(0, 4, 0, 3, samples=1)
>>> rays.shape, rays.dtype
((12, 6), dtype('float32'))
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from render.errors import RenderInputError
from render.limits import MAX_COORDINATE_MM, MIN_FOV_DEG

__all__ = ["Camera", "DEFAULT_VIEW_DIRECTION"]

#: Default direction from the object toward the camera in :meth:`Camera.framing`
#: (z up): a three-quarter view from the front right, slightly above.
DEFAULT_VIEW_DIRECTION: tuple[float, float, float] = (0.55, -1.0, 0.6)


def _vec3(value: ArrayLike, name: str) -> NDArray[np.float64]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RenderInputError(f"camera {name} must be three numbers (x, y, z), got {value!r}") from exc
    if arr.shape != (3,):
        raise RenderInputError(f"camera {name} must be three numbers (x, y, z), got {value!r}")
    if not np.all(np.isfinite(arr)):
        raise RenderInputError(f"camera {name} must be finite, got {arr.tolist()}")
    if name != "up" and float(np.abs(arr).max()) > MAX_COORDINATE_MM:
        raise RenderInputError(f"camera {name} {arr.tolist()} lies beyond +-{MAX_COORDINATE_MM:g} mm, the range "
                               "float32 ray casting resolves: bring it nearer the scene")
    return arr


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Parameters
    ----------
    eye, target
        Camera position and the point it looks at (scene units, mm), each
        coordinate within ``render.limits.MAX_COORDINATE_MM``.
    up
        Approximate up direction of the image; must not be parallel to the
        viewing direction.
    fov_deg
        Vertical field of view in degrees, from ``render.limits.MIN_FOV_DEG``
        (0.1, the narrowest float32 ray directions resolve) up to 180, 180 excluded.
    width, height
        Image size in pixels (positive integers).

    Raises
    ------
    RenderInputError
        Zero-size image, ``eye == target``, ``up`` parallel to the view
        direction, a field of view outside (0, 180) degrees, non-finite
        coordinates.
    """

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float]
    fov_deg: float
    width: int
    height: int

    def __post_init__(self) -> None:
        eye = _vec3(self.eye, "eye")
        target = _vec3(self.target, "target")
        up = _vec3(self.up, "up")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise RenderInputError(
                    f"camera {name} must be a positive whole number of pixels, got {value!r}"
                )
        fov = float(self.fov_deg)
        if not (math.isfinite(fov) and MIN_FOV_DEG <= fov < 180.0):
            raise RenderInputError(
                f"camera fov_deg (vertical field of view) must be from {MIN_FOV_DEG:g} (the narrowest float32 ray "
                f"casting resolves) to 180 degrees, 180 excluded, got {self.fov_deg!r}"
            )
        view = target - eye
        dist = float(np.linalg.norm(view))
        if dist <= 1e-12 * max(1.0, float(np.abs(eye).max())):
            raise RenderInputError(
                f"camera eye and target are the same point {eye.tolist()}: move the eye away from the target"
            )
        up_len = float(np.linalg.norm(up))
        if up_len == 0.0:
            raise RenderInputError("camera up vector is zero: give a direction such as (0, 0, 1)")
        sin_angle = float(np.linalg.norm(np.cross(view / dist, up / up_len)))
        if sin_angle < 1e-6:
            raise RenderInputError(
                f"camera up {up.tolist()} is parallel to the viewing direction {(view / dist).tolist()}: "
                "choose an up vector perpendicular to the line from eye to target"
            )
        object.__setattr__(self, "eye", tuple(eye.tolist()))
        object.__setattr__(self, "target", tuple(target.tolist()))
        object.__setattr__(self, "up", tuple(up.tolist()))
        object.__setattr__(self, "fov_deg", fov)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # ------------------------------------------------------------------ geometry
    def basis(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Orthonormal camera frame ``(right, up, forward)``.

        Returns
        -------
        tuple of ndarray
            Three unit ``(3,)`` vectors: image right, image up, viewing
            direction (right-handed: ``right x forward = up``).

        Examples
        --------
        >>> cam = Camera((0, -5, 0), (0, 0, 0), (0, 0, 1), 40, 4, 3)
        >>> [v.round(6).tolist() for v in cam.basis()]
        [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]
        """
        forward = np.subtract(self.target, self.eye)
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        return right, up, forward

    @property
    def aspect(self) -> float:
        """Width over height."""
        return self.width / self.height

    def project(self, points: ArrayLike) -> NDArray[np.float64]:
        """Image coordinates (x, y) in pixels of world ``points`` (..., 3).

        Pixel centres are at half-integers; points behind the camera get NaN.

        Parameters
        ----------
        points
            ``(..., 3)`` positions (scene units).

        Returns
        -------
        ndarray
            ``(..., 2)`` column and row in pixels (row 0 at the top).

        Examples
        --------
        >>> cam = Camera((0, -5, 0), (0, 0, 0), (0, 0, 1), 40, 4, 3)
        >>> cam.project([0, 0, 0]).tolist()
        [2.0, 1.5]
        """
        pts = np.asarray(points, dtype=np.float64) - np.asarray(self.eye)
        right, up, forward = self.basis()
        z = pts @ forward
        tan_half = math.tan(math.radians(self.fov_deg) / 2.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (pts @ right) / (z * tan_half * self.aspect)
            b = (pts @ up) / (z * tan_half)
        x = (a + 1.0) * 0.5 * self.width
        y = (1.0 - b) * 0.5 * self.height
        out = np.stack([x, y], axis=-1)
        return np.where((z > 0)[..., None], out, np.nan)

    # ------------------------------------------------------------------ rays
    def sample_offsets(
        self, n_pixels: int, samples: int, rng: np.random.Generator | None, jitter: bool = True
    ) -> NDArray[np.float32]:
        """Sub-pixel sample positions in [0, 1)^2, shape ``(n_pixels, samples, 2)``.

        One sample: the pixel centre.  More: one sample per stratum of a
        ``k x ceil(s/k)`` grid, ``k = ceil(sqrt(s))``, at a random position in
        the stratum (``jitter=True``) or on a rotated ordered grid (for four
        samples the rotated-grid pattern (3/8, 1/8), (7/8, 3/8), (1/8, 5/8),
        (5/8, 7/8)): no two samples share a pixel row or column, which
        anti-aliases near-horizontal and near-vertical edges better than the
        strata centres, and the pattern's mean is the pixel centre, so
        linearly varying shading is averaged exactly.

        Parameters
        ----------
        n_pixels
            Number of pixels.
        samples
            Samples per pixel (a whole number >= 1).
        rng
            Generator of the jitter (needed when ``jitter`` and ``samples > 1``).
        jitter
            Random positions within the strata (True) or the rotated
            ordered grid (False).

        Returns
        -------
        ndarray
            float32 ``(n_pixels, samples, 2)``, in pixel units.

        Raises
        ------
        RenderInputError
            ``samples`` is not a whole number >= 1, or a jittered pattern
            has no ``rng``.

        Examples
        --------
        >>> cam = Camera((0, -5, 0), (0, 0, 0), (0, 0, 1), 40, 4, 3)
        >>> off = cam.sample_offsets(2, 4, np.random.default_rng(0))
        >>> bool(np.all((off[:, :, 0] < 0.5) == np.array([True, False, True, False])))
        True
        """
        if isinstance(samples, bool) or int(samples) != samples or samples < 1:
            raise RenderInputError(f"samples per pixel must be a whole number >= 1, got {samples!r}")
        samples = int(samples)
        if samples == 1:
            return np.full((n_pixels, 1, 2), 0.5, dtype=np.float32)
        k = math.ceil(math.sqrt(samples))
        rows = math.ceil(samples / k)
        j = np.arange(samples)
        cell = np.stack([j % k, j // k], axis=-1).astype(np.float32)      # (s, 2)
        size = np.array([k, rows], dtype=np.float32)
        if not jitter:
            # rotated ordered grid: within its stratum (cx, cy) sample j sits at
            # (1 - (cy + 1/2) / rows, (cx + 1/2) / k), so no two samples share a column or row
            # (N-rooks) and the pattern is symmetric about the pixel centre.
            inner = np.stack([1.0 - (cell[:, 1] + 0.5) / rows, (cell[:, 0] + 0.5) / k], axis=-1)
            grid = ((cell + inner) / size).astype(np.float32)
            return np.ascontiguousarray(np.broadcast_to(grid, (n_pixels, samples, 2)))
        if rng is None:
            raise RenderInputError("jittered samples need a random generator (rng)")
        offsets = rng.random((n_pixels, samples, 2), dtype=np.float32)
        offsets += cell
        offsets /= size
        return offsets

    def rays(
        self,
        x0: int,
        x1: int,
        y0: int,
        y1: int,
        samples: int = 1,
        rng: np.random.Generator | None = None,
        jitter: bool = True,
    ) -> NDArray[np.float32]:
        """Primary rays of the pixel block ``[x0, x1) x [y0, y1)``.

        Parameters
        ----------
        x0, x1, y0, y1
            The block's columns ``[x0, x1)`` and rows ``[y0, y1)`` (pixels).
        samples, rng, jitter
            As in :meth:`sample_offsets`.

        Returns
        -------
        ndarray
            float32 ``(n, 6)`` rows ``(ox, oy, oz, dx, dy, dz)`` with unit
            directions, ordered by row, then column, then sample
            (``n = (y1-y0) (x1-x0) samples``).
        """
        if not (0 <= x0 < x1 <= self.width and 0 <= y0 < y1 <= self.height):
            raise RenderInputError(
                f"pixel block x[{x0}, {x1}) y[{y0}, {y1}) is outside the {self.width}x{self.height} image"
            )
        ny, nx = y1 - y0, x1 - x0
        offsets = self.sample_offsets(ny * nx, samples, rng, jitter)
        sx, sy, cols, rows = self._image_plane(np.arange(x0, x1), np.arange(y0, y1))
        # image-plane coordinates a (right), b (up) of every sample, forward at distance 1
        a = (offsets[:, :, 0] * sx).reshape(ny, nx, -1)
        a += cols[None, :, None]
        b = (offsets[:, :, 1] * -sy).reshape(ny, nx, -1)
        b += rows[:, None, None]
        return self._assemble(a.ravel(), b.ravel())

    def pixel_rays(
        self,
        xs: NDArray[np.integer],
        ys: NDArray[np.integer],
        samples: int = 1,
        rng: np.random.Generator | None = None,
        jitter: bool = True,
    ) -> NDArray[np.float32]:
        """Primary rays of the pixels ``(xs[i], ys[i])`` (any set of pixels, e.g. those to refine).

        The same rays as :meth:`rays` gives for those pixels (bit for bit
        without jitter), ordered by pixel, then sample.

        Parameters
        ----------
        xs, ys
            Columns and rows of the pixels (same length).
        samples, rng, jitter
            As in :meth:`sample_offsets`.

        Returns
        -------
        ndarray
            float32 ``(len(xs) * samples, 6)`` rows ``(ox, oy, oz, dx, dy, dz)``
            with unit directions.

        Raises
        ------
        RenderInputError
            ``xs`` and ``ys`` differ in length, or a pixel is outside the
            image.

        Examples
        --------
        >>> cam = Camera((0, -5, 0), (0, 0, 0), (0, 0, 1), 40, 4, 3)
        >>> block = cam.rays(0, 4, 0, 3, 4, jitter=False)
        >>> some = cam.pixel_rays(np.array([3, 1]), np.array([0, 2]), 4, jitter=False)
        >>> bool(np.array_equal(some, block.reshape(3, 4, 4, 6)[[0, 2], [3, 1]].reshape(-1, 6)))
        True
        """
        xs = np.asarray(xs).ravel()
        ys = np.asarray(ys).ravel()
        if xs.shape != ys.shape:
            raise RenderInputError(f"pixel_rays: xs and ys must have the same length, got {xs.size} and {ys.size}")
        if xs.size and (xs.min() < 0 or xs.max() >= self.width or ys.min() < 0 or ys.max() >= self.height):
            raise RenderInputError(f"pixel_rays: pixels outside the {self.width}x{self.height} image")
        offsets = self.sample_offsets(xs.size, samples, rng, jitter)
        sx, sy, cols, rows = self._image_plane(xs, ys)
        a = offsets[:, :, 0] * sx
        a += cols[:, None]
        b = offsets[:, :, 1] * -sy
        b += rows[:, None]
        return self._assemble(a.ravel(), b.ravel())

    def _image_plane(
        self, xs: NDArray[np.integer], ys: NDArray[np.integer]
    ) -> tuple[np.float32, np.float32, NDArray[np.float32], NDArray[np.float32]]:
        """Pixel size (sx, sy) on the image plane at distance 1 and the left / top edges of columns / rows."""
        tan_half = math.tan(math.radians(self.fov_deg) / 2.0)
        sx = np.float32(2.0 * tan_half * self.aspect / self.width)
        sy = np.float32(2.0 * tan_half / self.height)
        cols = np.asarray(xs, dtype=np.float32) * sx - np.float32(tan_half * self.aspect)
        rows = np.float32(tan_half) - np.asarray(ys, dtype=np.float32) * sy
        return sx, sy, cols, rows

    def _assemble(self, a: NDArray[np.float32], b: NDArray[np.float32]) -> NDArray[np.float32]:
        """Unit ray rows ``(n, 6)`` through image-plane points ``(a, b)`` (forward at distance 1)."""
        inv = np.float32(1.0) / np.sqrt(a * a + b * b + np.float32(1.0))
        a *= inv
        b *= inv
        basis = np.stack(self.basis()).astype(np.float32)              # rows: right, up, forward
        out = np.empty((a.size, 6), dtype=np.float32)
        out[:, :3] = np.asarray(self.eye, dtype=np.float32)
        out[:, 3:] = np.stack([a, b, inv], axis=1) @ basis
        return out

    # ------------------------------------------------------------------ framing
    @classmethod
    def framing(
        cls,
        bounds_min: ArrayLike,
        bounds_max: ArrayLike,
        width: int,
        height: int,
        fov_deg: float = 35.0,
        direction: ArrayLike = DEFAULT_VIEW_DIRECTION,
        up: ArrayLike = (0.0, 0.0, 1.0),
        margin: float = 1.05,
    ) -> Camera:
        """A camera that frames the box ``[bounds_min, bounds_max]``.

        The eye lies along ``direction`` (from the box centre toward the
        camera) at the distance where the box's bounding sphere, enlarged by
        ``margin``, just fits the narrower field of view.

        Parameters
        ----------
        bounds_min, bounds_max
            Corners of the box (scene units).
        width, height
            Image size in pixels.
        fov_deg
            Vertical field of view in degrees.
        direction
            Direction from the box centre toward the eye (any length).
        up
            Approximate up direction of the image.
        margin
            Factor (> 0) on the bounding sphere's radius.

        Returns
        -------
        Camera
            Looking at the box centre.

        Raises
        ------
        RenderInputError
            Inverted or single-point bounds, a zero direction, a margin
            <= 0, or camera parameters :class:`Camera` refuses.

        Examples
        --------
        >>> cam = Camera.framing((-1, -1, -1), (1, 1, 1), 64, 48, direction=(0, -1, 0))
        >>> round(cam.eye[1], 3), cam.target
        (-6.048, (0.0, 0.0, 0.0))
        """
        lo = _vec3(bounds_min, "bounds_min")
        hi = _vec3(bounds_max, "bounds_max")
        if np.any(hi < lo):
            raise RenderInputError(
                f"camera framing: bounds_max {hi.tolist()} is below bounds_min {lo.tolist()}"
            )
        radius = 0.5 * float(np.linalg.norm(hi - lo))
        if radius <= 0.0:
            raise RenderInputError(
                "camera framing: the bounds are a single point, there is nothing to frame"
            )
        d = _vec3(direction, "direction")
        dn = float(np.linalg.norm(d))
        if dn == 0.0:
            raise RenderInputError("camera framing: direction is zero; give the direction toward the camera")
        if not (math.isfinite(margin) and margin > 0):
            raise RenderInputError(f"camera framing: margin must be > 0, got {margin!r}")
        if isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer)) and width > 0 and height > 0:
            aspect = width / height
        else:
            aspect = 1.0   # the constructor below reports the bad size
        fov = float(fov_deg)
        half_v = math.radians(fov) / 2.0 if 0.0 < fov < 180.0 else math.radians(35.0) / 2.0
        half_h = math.atan(math.tan(half_v) * aspect)
        half = min(half_v, half_h)
        dist = radius * margin / math.sin(half)
        centre = 0.5 * (lo + hi)
        eye = centre + d / dn * dist
        return cls(tuple(eye.tolist()), tuple(centre.tolist()), up, fov_deg, width, height)
