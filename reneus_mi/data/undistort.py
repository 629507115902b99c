"""Photographs through a real lens, resampled to the pinhole camera the renderer has.

reneus-mi's cameras are pinholes (:mod:`reneus_mi.data.cameras`): every pixel's ray is
``K⁻¹ (u, v, 1)``. A photograph has lens distortion, which OpenCV's model (k1, k2, p1, p2,
k3; the same as COLMAP's ``OPENCV`` and nerfstudio's ``camera_model: OPENCV``) describes.
:func:`undistort` is the one code path that turns such a photograph into a pinhole image:
the capture command, the COLMAP reader and the nerfstudio loader all call it.

Each output pixel's centre is taken through the pinhole ``K_out`` to a direction, through
the lens model to where the photograph saw that direction, and sampled there (bilinear).
Shrinking is done first by area averaging (``cv2.INTER_AREA``), so that a 24-megapixel
photograph scaled to a few hundred pixels does not alias. Pixels whose source lies outside
the photograph are black and marked invalid.
"""
from __future__ import annotations

import cv2
import numpy as np

from reneus_mi.data.images import reduction, scaled_size
from reneus_mi.utils.errors import ReneusError

#: Distortion coefficients in OpenCV's order.
DISTORTION_KEYS = ('k1', 'k2', 'p1', 'p2', 'k3')


def opencv_K(K: np.ndarray) -> np.ndarray:
    """``K`` with OpenCV's pixel convention (the top-left pixel's centre at (0, 0), where
    reneus-mi and COLMAP put it at (0.5, 0.5))."""
    out = np.array(K, np.float64)
    out[:2, 2] -= 0.5
    return out


def distortion(values, where: str) -> np.ndarray:
    """The five coefficients (k1, k2, p1, p2, k3) as float64; fewer are padded with zeros."""
    d = np.zeros(5)
    v = np.asarray(values, np.float64).ravel()
    if v.size > 5 or not np.all(np.isfinite(v)):
        raise ReneusError(f"{where}: distortion {v.tolist()}; expected up to five finite numbers "
                          f"({', '.join(DISTORTION_KEYS)})")
    d[:v.size] = v
    return d


def output_size(width: int, height: int, *, max_size: int | None = None,
                downscale: float | None = None) -> tuple[int, int, float]:
    """Output size and scale factor: at most ``max_size`` pixels on a side, or 1/``downscale``."""
    if max_size is None and downscale is not None:
        scale = 1.0 / downscale
    else:
        scale = reduction(width, height, max_size or 0)
    return *scaled_size(width, height, scale), scale


def pinhole_K(K: np.ndarray, scale: float) -> np.ndarray:
    """The pinhole intrinsics of the output: ``K`` with square pixels, scaled by ``scale``."""
    f = 0.5 * (K[0, 0] + K[1, 1])
    return np.array([[f * scale, 0.0, K[0, 2] * scale], [0.0, f * scale, K[1, 2] * scale], [0.0, 0.0, 1.0]])


def undistort(image: np.ndarray, K: np.ndarray, dist, K_out: np.ndarray,
              size_out: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``image`` (H,W[,C]) seen through ``K``, ``dist`` resampled to the pinhole ``K_out``.

    ``size_out`` is (width, height). Returns the image (same dtype) and the (h,w) bool mask of
    pixels that the photograph covers. Intrinsics in reneus-mi's pixel convention.
    """
    h, w = image.shape[:2]
    width, height = size_out
    K_src = np.array(K, np.float64)
    scale = K_out[0, 0] / K_src[0, 0]
    if scale < 1.0:
        # Area averaging to the output's sampling first; K follows the resize exactly.
        small = scaled_size(w, h, scale)
        image = cv2.resize(image, small, interpolation=cv2.INTER_AREA)
        K_src = np.diag([small[0] / w, small[1] / h, 1.0]) @ K_src
        h, w = image.shape[:2]
    d = np.asarray(dist, np.float64)
    map_x, map_y = cv2.initUndistortRectifyMap(opencv_K(K_src), d, None, opencv_K(K_out),
                                               (width, height), cv2.CV_32FC1)
    out = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    valid = (map_x >= -0.5) & (map_x <= w - 0.5) & (map_y >= -0.5) & (map_y <= h - 0.5)
    return out, valid
