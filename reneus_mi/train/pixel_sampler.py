"""Camera rays of the photographs, drawn and built on the device.

The photographs, the container masks' pixel indices and the cameras are
uploaded once as Dr.Jit arrays. A batch is a set of masked pixels drawn with
Dr.Jit's PCG32 from a state that depends only on ``(seed, step)``
(:mod:`reneus_mi.render.seeds`): a run resumed at step k draws what the unbroken
run drew, and no NumPy array is touched during training.

Two choices of :class:`PixelSamplerConfig` are for thin parts, a leg one or two pixels
wide. A pixel is an area: its ray goes through a random point of it (``jitter``), so that
what the photograph averages over the pixel (the leg covering a share of it) is what the
renders average over the steps; through the centre only, a leg between two centres is
never seen. And a share of each batch (``error_share``) is drawn in proportion to the
colour error that each pixel had when it was last drawn: a leg two pixels wide is 1-2 % of
the container's pixels, and the body's pixels, fitted early, keep taking the rest. The
error of the pixels is the sampler's state (saved in the checkpoint: a resumed run draws
what the unbroken one drew).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.ndimage import distance_transform_edt

from reneus_mi.render.seeds import PIXELS, opaque_seed, step_seed
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.validate import check_numbers

if TYPE_CHECKING:   # the config imports this module, and the dataset's module the config
    from reneus_mi.data import Dataset


@dataclass
class PixelSamplerConfig:
    """Which pixels a training batch draws, and where in each its ray goes."""

    jitter: bool = True
    """Rays through a random point of each pixel (False: through its centre)."""
    error_share: float = 0.5
    """Share of each batch drawn in proportion to each pixel's colour error when it was last
    drawn (the rest uniformly over the container's pixels; 0: all uniformly)."""
    error_refresh: int = 32
    """Steps between rebuilds of the error's distribution (a prefix sum over every pixel)."""

    def __post_init__(self):
        check_numbers(self, positive=('error_refresh',))
        if not 0.0 <= self.error_share <= 1.0:
            raise ReneusError(f'error_share={self.error_share}: expected a share in [0, 1]')


#: Bytes per photograph pixel that the sampler holds beyond the dataset: the colours on the
#: device (12), the masked pixels' indices (4) and, for batches drawn by error, their errors and
#: its prefix sum (8); the int64 indices it builds them from fit in what loading the dataset
#: freed (``python bench/memory.py``).
BYTES_PER_PIXEL = 24


class PixelSampler:
    """Masked pixels of all views, their colours and their camera rays, on the device."""

    def __init__(self, dataset: Dataset, seed: int = 0, margin: float = 0.0,
                 config: PixelSamplerConfig | None = None):
        """``margin`` widens each view's mask by that fraction of the container's radius in it."""
        self.config = config or PixelSamplerConfig()
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
        # Unseen pixels count as badly fitted (errors are mean absolute colour differences).
        self.error = dr.full(mi.Float, 1.0, self.n_pixels) if self.config.error_share else None
        self.cdf = _cdf(self.error) if self.error is not None else None
        self.drawn: mi.UInt32 | None = None

    def batch(self, step: int, n: int) -> tuple[mi.Ray3f, mi.Color3f]:
        """``n`` camera rays through random masked pixels, and the photographs' colours there."""
        cfg = self.config
        rng = mi.PCG32(n, initstate=opaque_seed(step_seed(self.seed, step, PIXELS)))
        slot = rng.next_uint32_bounded(self.n_pixels)
        if self.error is not None:
            if step % cfg.error_refresh == 0:
                self.cdf = _cdf(self.error)
            total = dr.gather(mi.Float, self.cdf, self.n_pixels - 1)
            u = rng.next_float32() * total
            by_error = dr.binary_search(0, self.n_pixels - 1, lambda k: dr.gather(mi.Float, self.cdf, k) <= u)
            uniform = self.uniform_lanes(n)
            slot = by_error if uniform is None else dr.select(uniform, slot, by_error)
            self.drawn = slot
        index = dr.gather(mi.UInt32, self.pixels, slot)
        offset = (rng.next_float32(), rng.next_float32()) if cfg.jitter else (0.5, 0.5)
        return self.rays(index, offset), self.color(index)

    def uniform_lanes(self, n: int) -> mi.Bool | None:
        """Which of a batch's ``n`` rays are drawn uniformly (None: all of them, or none)."""
        if self.error is None or self.config.error_share == 1.0:
            return None
        return mi.Float(dr.arange(mi.UInt32, n)) < dr.opaque(mi.Float, (1.0 - self.config.error_share) * n)

    def record(self, color: mi.Color3f, target: mi.Color3f) -> None:
        """The colour error of the batch just drawn, per pixel, for the next draws by error."""
        if self.error is not None:
            dr.scatter(self.error, dr.mean(dr.abs(dr.detach(color) - target), axis=0), self.drawn)

    def state(self) -> dict[str, np.ndarray]:
        """What a checkpoint keeps of the sampler."""
        if self.error is None:
            return {}
        return {'error': np.asarray(self.error, np.float32), 'cdf': np.asarray(self.cdf, np.float32)}

    def load(self, state: dict[str, np.ndarray], where: str) -> None:
        if self.error is None:
            return
        if 'error' not in state or len(state['error']) != self.n_pixels:
            raise ReneusError(f'{where}: no pixel errors for the {self.n_pixels} pixels of this dataset; '
                              'expected the checkpoint of a run with train.pixels.error_share > 0 on it')
        self.error, self.cdf = mi.Float(state['error']), mi.Float(state['cdf'])

    def view(self, view: int, stride: int = 1) -> mi.UInt32:
        """Flat indices of every ``stride``-th pixel of a view, row by row."""
        ys, xs = np.mgrid[0:self.height:stride, 0:self.width:stride]
        return mi.UInt32(((view * self.height + ys) * self.width + xs).reshape(-1).astype(np.uint32))

    def color(self, index: mi.UInt32) -> mi.Color3f:
        return dr.gather(mi.Color3f, self.colors, index)

    def rays(self, index: mi.UInt32, offset=(0.5, 0.5)) -> mi.Ray3f:
        """World rays through the pixels with flat indices (view, y, x), at ``offset`` (x, y)
        within each (the centre by default)."""
        hw = self.height * self.width
        view = index // hw
        rest = index - view * hw
        y = rest // self.width
        x = rest - y * self.width
        uv1 = mi.Vector3f(mi.Float(x) + offset[0], mi.Float(y) + offset[1], 1.0)
        # K⁻¹ of a pinhole has (0, 0, 1) as its last row.
        d_cam = mi.Vector3f(dr.dot(dr.gather(mi.Vector3f, self.k_inv, 2 * view), uv1),
                            dr.dot(dr.gather(mi.Vector3f, self.k_inv, 2 * view + 1), uv1), 1.0)
        d = mi.Vector3f(*[dr.dot(dr.gather(mi.Vector3f, self.rotation, 3 * view + i), d_cam)
                          for i in range(3)])
        return mi.Ray3f(dr.gather(mi.Point3f, self.origin, view), dr.normalize(d))


def _cdf(weights: mi.Float) -> mi.Float:
    """The inclusive prefix sum of ``weights``: pixel k is drawn where u lies in [cdf[k-1], cdf[k])."""
    cdf = dr.prefix_reduce(dr.ReduceOp.Add, weights, exclusive=False)
    dr.eval(cdf)
    return cdf


def widen(masks: np.ndarray, margin: float) -> np.ndarray:
    """Masks grown by ``margin`` times the radius of a disc of the same area, view by view."""
    out = masks.copy()
    for v, mask in enumerate(masks):
        radius = np.sqrt(mask.sum() / np.pi)
        if radius > 0:
            out[v] = distance_transform_edt(~mask) <= margin * radius
    return out
