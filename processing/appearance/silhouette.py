"""The mesh's outline in a frame against the object's outline in the photo.

:func:`mesh_mask` casts the mesh through the frame's pixels;
:func:`object_mask` segments the object from a uniform backdrop;
:func:`silhouette_check` compares the two (IoU and the mean distance between
their boundaries), which measures how well a frame is posed;
:func:`outline_px` gives the mesh's outline as polylines for overlays.

References
----------
Borgefors, G. (1986). Distance transformations in digital images. Computer
Vision, Graphics, and Image Processing 34(3), 344-371.
doi:10.1016/S0734-189X(86)80047-0

Suzuki, S., Abe, K. (1985). Topological structural analysis of digitized
binary images by border following. CVGIP 30(1), 32-46.
doi:10.1016/0734-189X(85)90016-7
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from processing.appearance.frame_poses import AppearanceError, FramePose
from processing.appearance.projection import depth_map, mesh_arrays, raycasting_scene

__all__ = ["mesh_mask", "object_mask", "silhouette_check", "outline_px"]


def mesh_mask(mesh: Any, frame_pose: FramePose, *, binning: int = 1, scene: Any = None) -> NDArray[np.bool_]:
    """Pixels of a frame through which a ray hits the mesh (distortion model included).

    Parameters
    ----------
    mesh
        Open3D ``TriangleMesh`` or ``(vertices, triangles)`` in M.
    frame_pose
        The frame.
    binning
        Cast one ray per ``binning`` x ``binning`` block and repeat it
        (nearest) to full resolution: faster, outline within ``binning`` px.
    scene
        A prebuilt ray casting scene of the same mesh.

    Returns
    -------
    ndarray
        ``(height, width)`` bool.
    """
    if scene is None:
        v, f, _ = mesh_arrays(mesh)
        scene = raycasting_scene(v, f)
    b = int(binning)
    if b < 1:
        raise AppearanceError(f"mesh_mask binning {binning!r}: give a whole number >= 1")
    hit = np.isfinite(depth_map(scene, frame_pose, b))
    w, h = frame_pose.image_size
    if b > 1:
        hit = np.repeat(np.repeat(hit, b, axis=0), b, axis=1)
    return np.ascontiguousarray(hit[:h, :w])


def _backdrop(img: NDArray[np.float64], border: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    ring = np.concatenate([img[:border].reshape(-1, img.shape[2]), img[-border:].reshape(-1, img.shape[2]),
                           img[:, :border].reshape(-1, img.shape[2]), img[:, -border:].reshape(-1, img.shape[2])])
    med = np.median(ring, axis=0)
    mad = 1.4826 * np.median(np.abs(ring - med), axis=0)
    floor = 1e-3 * max(float(np.max(np.abs(med))), 1e-12)
    return med, np.maximum(mad, floor)


def object_mask(image: ArrayLike, *, name: str, threshold_sigma: float = 6.0, border_frac: float = 0.02,
                keep_frac: float = 0.1) -> NDArray[np.bool_]:
    """Pixels of a photo that are the object, against a uniform backdrop.

    Assumption: the backdrop is uniform (one colour up to noise) and fills
    the image border (a ring ``border_frac`` of the smaller side wide); the
    object does not touch the border.  The backdrop colour is the border's
    per-channel median and its noise the border's MAD; a pixel is object
    when any channel differs by more than ``threshold_sigma`` noise units.
    A 3 x 3 opening removes isolated noise, connected components smaller
    than ``keep_frac`` of the largest are dropped and holes are filled.
    Finally the outline is placed where a pixel is half covered: a pixel of
    the 2-pixel rim counts as object when its difference from the backdrop
    projected on that of the nearest pixel further inside is at least half
    of it (coverage >= 0.5), so the mask neither grows by the partly covered
    pixels a noise threshold catches nor depends on the object's brightness.

    Parameters
    ----------
    image
        ``(H, W)`` or ``(H, W, C)`` linear image.
    name
        The frame's name, for errors.
    threshold_sigma
        Threshold in backdrop noise units.
    border_frac
        Width of the border ring as a fraction of ``min(H, W)`` (>= 2 px).
    keep_frac
        Components at least this fraction of the largest are kept.

    Returns
    -------
    ndarray
        ``(H, W)`` bool.
    """
    img = np.asarray(image, dtype=np.float64)
    img = img[..., None] if img.ndim == 2 else img
    if img.ndim != 3 or min(img.shape[:2]) < 8 or not np.all(np.isfinite(img)):
        raise AppearanceError(f"frame {name!r}: object_mask needs a finite (H, W[, C]) image at least 8 x 8")
    border = max(2, int(border_frac * min(img.shape[:2])))
    med, sigma = _backdrop(img, border)
    fg = (np.max(np.abs(img - med) / sigma, axis=2) > threshold_sigma).astype(np.uint8)
    fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if count < 2:
        raise AppearanceError(f"frame {name!r}: no object found against the backdrop; check the exposure and framing")
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.zeros(count, dtype=bool)
    keep[1:] = areas >= keep_frac * areas.max()
    return _half_covered(ndimage.binary_fill_holes(keep[labels]), img - med)


def _half_covered(mask: NDArray[np.bool_], diff: NDArray[np.float64], rim_px: int = 2) -> NDArray[np.bool_]:
    """``mask`` with its rim pixels kept only where the object covers at least half of them.

    A rim pixel's colour is ``a * object + (1 - a) * backdrop``; its difference from the backdrop
    projected on the difference of the nearest interior pixel estimates the coverage ``a``.
    """
    k = 2 * rim_px + 1
    inner = cv2.erode(mask.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    if not inner.any():
        return mask
    _, (iy, ix) = ndimage.distance_transform_edt(~inner, return_indices=True)
    ref = diff[iy, ix]
    cover = np.sum(diff * ref, axis=2) / np.maximum(np.sum(ref * ref, axis=2), 1e-30)
    return inner | (mask & ~inner & (cover >= 0.5))


def _boundary(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    m = mask.astype(np.uint8)
    return mask & ~cv2.erode(m, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE).astype(bool)


def silhouette_check(mesh_mask: ArrayLike, object_mask: ArrayLike) -> dict[str, float]:
    """How well the mesh's outline matches the object's in one frame.

    Parameters
    ----------
    mesh_mask
        ``(H, W)`` bool, :func:`mesh_mask`.
    object_mask
        ``(H, W)`` bool, :func:`object_mask`.

    Returns
    -------
    dict
        ``iou`` (intersection over union) and ``offset_px``: the mean
        distance from each mask's boundary pixels to the other's boundary,
        both directions pooled (distance transform).

    Examples
    --------
    >>> import numpy as np
    >>> a = np.zeros((20, 20), bool); a[5:15, 5:15] = True
    >>> b = np.zeros((20, 20), bool); b[5:15, 6:16] = True
    >>> r = silhouette_check(a, b); round(r["iou"], 3), round(r["offset_px"], 2)
    (0.818, 0.5)
    """
    a, b = np.asarray(mesh_mask, dtype=bool), np.asarray(object_mask, dtype=bool)
    if a.shape != b.shape or a.ndim != 2:
        raise AppearanceError(f"silhouette_check: masks of shapes {a.shape} and {b.shape}; give two equal (H, W)")
    if not a.any() or not b.any():
        raise AppearanceError("silhouette_check: a mask is empty; the mesh or the object is not in the frame")
    iou = float(np.count_nonzero(a & b) / np.count_nonzero(a | b))
    ba, bb = _boundary(a), _boundary(b)
    da = cv2.distanceTransform((~ba).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    db = cv2.distanceTransform((~bb).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    offset = float(np.mean(np.concatenate([db[ba], da[bb]])))
    return {"iou": iou, "offset_px": offset}


def outline_px(mesh_mask: ArrayLike) -> list[NDArray[np.float64]]:
    """The outlines of a mask as closed polylines of pixel positions, for overlays.

    Parameters
    ----------
    mesh_mask
        ``(H, W)`` bool.

    Returns
    -------
    list of ndarray
        ``(N, 2)`` (column, row) polylines, outer outlines and holes
        (``cv2.findContours``, simple chain approximation).
    """
    m = np.asarray(mesh_mask, dtype=bool)
    if m.ndim != 2:
        raise AppearanceError(f"outline_px: mask of shape {m.shape}; give an (H, W) mask")
    contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
    return [c.reshape(-1, 2).astype(np.float64) for c in contours]
