"""The container's region of each photograph, at the dataset's full resolution.

Training uses only the pixels where the container is seen (its projection: the paper's
M_in), and a museum's photograph of a 40 mm block on its board shows the block in a few
percent of the frame. So the dataset keeps, of each view, a window around the container's
projection: one size for all views (the dataset's images are one array), each window with
its own intrinsics (the principal point moved by the window's corner; transforms.json's
per-frame ``cx``, ``cy``), at the output scale: the photographs' own pixels unless
``--max-size`` or ``--downscale`` says otherwise. A leg five pixels wide in the photograph
stays five pixels wide in the dataset.

The capture's other stages (registration, exposures, overlays) see every view whole, at
most :data:`WORK_MAX_SIZE` pixels on a side; the windows are then undistorted from the
photographs themselves, decoded once more, one at a time per worker, so that 48 photographs
of 24 MP never have to be in memory at once.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from reneus_mi.data.undistort import undistort

#: Longest side in pixels of the copies the capture registers the container on and measures the
#: light in (the board's corners are found in the photographs themselves).
WORK_MAX_SIZE = 1600
#: Margin of a window around the container's projection, per side, as a fraction of the
#: projection's larger side: room for the container's place to be refined (the trainer widens
#: the masks by 0.1 of the container's radius in the image, POSE_MARGIN) and for what refraction
#: at its silhouette shows.
CROP_MARGIN = 0.15


@dataclasses.dataclass(frozen=True)
class Windows:
    """One window per view, all of one size, in the uncropped output frame."""
    #: (width, height) of every window, pixels.
    size: tuple[int, int]
    #: (N, 2) int: each window's top-left pixel (x, y) in the uncropped frame.
    corners: np.ndarray

    def K(self, K_frame: np.ndarray, view: int) -> np.ndarray:
        """The intrinsics of view ``view``'s window, from those of the uncropped frame (one
        (3,3) for all views or (N,3,3))."""
        K = np.array(K_frame if np.ndim(K_frame) == 2 else K_frame[view], np.float64)
        K[:2, 2] -= self.corners[view]
        return K


def container_windows(points: np.ndarray, K_frame: np.ndarray, c2w: np.ndarray,
                      frame: tuple[int, int]) -> Windows:
    """Windows around the projection of the container's ``points`` (world; its convex hull's
    vertices are enough) in every view of a frame of ``frame`` (width, height) pixels, seen
    through ``K_frame`` (one or one per view): the largest of the bounding boxes grown by
    :data:`CROP_MARGIN`, centred on each view's box and moved inside the frame (at most the
    frame itself)."""
    w2c = np.linalg.inv(c2w)
    boxes = []
    for v in range(len(c2w)):
        K = K_frame if np.ndim(K_frame) == 2 else K_frame[v]
        cam = points @ w2c[v, :3, :3].T + w2c[v, :3, 3]
        uv = cam @ K.T
        px = uv[:, :2] / np.maximum(uv[:, 2:], 1e-9)
        boxes.append((px.min(axis=0), px.max(axis=0)))
    extent = np.max([hi - lo for lo, hi in boxes], axis=0)
    grown = extent + 2.0 * CROP_MARGIN * extent.max()
    size = np.minimum(np.ceil(grown).astype(int), frame)
    corners = []
    for lo, hi in boxes:
        corner = np.floor(0.5 * (lo + hi) - 0.5 * size).astype(int)
        corners.append(np.clip(corner, 0, np.asarray(frame) - size))
    return Windows((int(size[0]), int(size[1])), np.array(corners, int))


class CroppedViews(Sequence):
    """The dataset's images: each view's window undistorted from its photograph (float32
    display values, its exposure normalised), computed when asked for."""

    def __init__(self, windows: Windows, K_frame: np.ndarray, lens_of: Callable[[int], tuple],
                 factors: np.ndarray | None = None):
        """``lens_of(v)``: view ``v``'s photograph (H,W,3 uint8), its intrinsics and its
        distortion; ``factors``: each view's exposure normalisation (display values; None: 1)."""
        self.windows, self.K_frame, self.lens_of, self.factors = windows, K_frame, lens_of, factors

    def __len__(self) -> int:
        return len(self.windows.corners)

    def __getitem__(self, view: int) -> np.ndarray:
        rgb, K, dist = self.lens_of(view)
        image, _ = undistort(rgb, K, dist, self.windows.K(self.K_frame, view), self.windows.size)
        factor = 1.0 if self.factors is None else self.factors[view]
        return image.astype(np.float32) * np.float32(factor / 255.0)
