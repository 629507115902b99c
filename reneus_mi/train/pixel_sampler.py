"""Camera rays of the photographs, drawn and built on the device.

The photographs, the container masks' pixel indices and the cameras are
uploaded once as Dr.Jit arrays. A batch is a set of masked pixels drawn with
Dr.Jit's PCG32 from a state that depends only on ``(seed, step)``
(:mod:`reneus_mi.render.seeds`): a run resumed at step k draws what the unbroken
run drew, and no NumPy array is touched during training.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.ndimage import distance_transform_edt

from reneus_mi.data import Dataset
from reneus_mi.render.seeds import PIXELS, opaque_seed, step_seed
from reneus_mi.utils.errors import ReneusError

#: Bytes per photograph pixel that the sampler holds beyond the dataset: the colours on the
#: device (12) and the masked pixels' indices (4); the int64 indices it builds them from fit in
#: what loading the dataset freed (``python bench/memory.py``).
BYTES_PER_PIXEL = 16


class PixelSampler:
    """Masked pixels of all views, their colours and their camera rays, on the device."""

    def __init__(self, dataset: Dataset, seed: int = 0, margin: float = 0.0):
        """``margin`` widens each view's mask by that fraction of the container's radius in it."""
        n, h, w = dataset.masks.shape
        masks = dataset.masks if margin == 0.0 else widen(dataset.masks, margin)
        pixels = np.flatnonzero(masks.reshape(-1))
        if len(pixels) == 0:
            raise ReneusError(f'{dataset.root}: no view sees the container (all masks are empty)')
        if n * h * w >= 2 ** 32:
            raise ReneusError(f'{dataset.root}: {n} views of {w}x{h} pixels exceed 2^32 pixel indices')
        self.seed, self.height, self.width = seed, h, w
        self.pixels = mi.UInt32(pixels.astype(np.uint32))
        self.n_pixels = len(pixels)
        self.colors = mi.Float(dataset.images.reshape(-1).astype(np.float32, copy=False))
        # Per view: rows of K⁻¹ and of the camera-to-world rotation, and the camera position.
        k_inv = np.linalg.inv(dataset.K)
        self.k_inv = mi.Float(k_inv[:, :2, :].reshape(-1).astype(np.float32))
        self.rotation = mi.Float(dataset.c2w[:, :3, :3].reshape(-1).astype(np.float32))
        self.origin = mi.Float(dataset.c2w[:, :3, 3].reshape(-1).astype(np.float32))

    def batch(self, step: int, n: int) -> tuple[mi.Ray3f, mi.Color3f]:
        """``n`` camera rays through random masked pixels, and the photographs' colours there."""
        rng = mi.PCG32(n, initstate=opaque_seed(step_seed(self.seed, step, PIXELS)))
        index = dr.gather(mi.UInt32, self.pixels, rng.next_uint32_bounded(self.n_pixels))
        return self.rays(index), self.color(index)

    def view(self, view: int, stride: int = 1) -> mi.UInt32:
        """Flat indices of every ``stride``-th pixel of a view, row by row."""
        ys, xs = np.mgrid[0:self.height:stride, 0:self.width:stride]
        return mi.UInt32(((view * self.height + ys) * self.width + xs).reshape(-1).astype(np.uint32))

    def color(self, index: mi.UInt32) -> mi.Color3f:
        return dr.gather(mi.Color3f, self.colors, index)

    def rays(self, index: mi.UInt32) -> mi.Ray3f:
        """World rays through the centres of the pixels with flat indices (view, y, x)."""
        hw = self.height * self.width
        view = index // hw
        rest = index - view * hw
        y = rest // self.width
        x = rest - y * self.width
        uv1 = mi.Vector3f(mi.Float(x) + 0.5, mi.Float(y) + 0.5, 1.0)
        # K⁻¹ of a pinhole has (0, 0, 1) as its last row.
        d_cam = mi.Vector3f(dr.dot(dr.gather(mi.Vector3f, self.k_inv, 2 * view), uv1),
                            dr.dot(dr.gather(mi.Vector3f, self.k_inv, 2 * view + 1), uv1), 1.0)
        d = mi.Vector3f(*[dr.dot(dr.gather(mi.Vector3f, self.rotation, 3 * view + i), d_cam)
                          for i in range(3)])
        return mi.Ray3f(dr.gather(mi.Point3f, self.origin, view), dr.normalize(d))


def widen(masks: np.ndarray, margin: float) -> np.ndarray:
    """Masks grown by ``margin`` times the radius of a disc of the same area, view by view."""
    out = masks.copy()
    for v, mask in enumerate(masks):
        radius = np.sqrt(mask.sum() / np.pi)
        if radius > 0:
            out[v] = distance_transform_edt(~mask) <= margin * radius
    return out
