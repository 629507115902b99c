"""Camera rays of the photographs, drawn and built on the device.

The container masks' pixel indices, the photographs' colours there (as the dataset holds
them: 8-bit integers for 8-bit photographs, half floats for 16-bit ones) and the cameras
are uploaded once as Dr.Jit arrays; pixels outside the masks cost the device nothing. A batch is a set of masked pixels drawn with
Dr.Jit's PCG32 from a state that depends only on ``(seed, step)``
(:mod:`reneus_mi.render.seeds`): a run resumed at step k draws what the unbroken
run drew, and no NumPy array is touched during training.

Two choices of :class:`PixelSamplerConfig` are for thin parts, a leg one or two pixels
wide. A pixel is an area: its ray goes through a random point of it (``jitter``), so that
what the photograph averages over the pixel (the leg covering a share of it) is what the
renders average over the steps; through the centre only, a leg between two centres is
never seen. And a share of each batch (``error_share``) is drawn in proportion to the
colour error that each pixel had when it was last drawn: a leg two pixels wide is 1-2 % of
the container's pixels, and the body's pixels, fitted early, keep taking the rest. Such a
draw picks a block of :data:`ERROR_BLOCK` pixels (a TILE x TILE tile of a photograph: the
masked pixels are ordered tile by tile) by the prefix sum of the blocks' errors (float64,
rebuilt every ``error_refresh`` steps), then a pixel within the block by the errors now: a
float32 prefix sum over tens of millions of pixels (a full-resolution capture) cannot resolve
one pixel's error against the total. A pixel never drawn takes, as an estimate, the last
error of a pixel drawn in its tile: a run of 12-megapixel photographs draws each pixel a
tenth of a time, and one that had to wait for its own draw would spend its batches on the
unseen body as much as on the legs. The errors and the blocks' prefix sum are the
sampler's state (saved in the checkpoint: a resumed run draws what the unbroken one drew).

Three more are options, measured but not defaults: several rays per drawn pixel, one per
stratum, whose mean is compared with the photograph's pixel (``rays_per_pixel``); two rays
through independent points of it, whose errors' product is the loss (``paired``,
:func:`reneus_mi.train.losses.paired_l1`); and the camera's blur beyond the pixel's area
(``blur``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.ndimage import distance_transform_edt

from reneus_mi.render.seeds import PIXELS, STRATA, opaque_seed, step_seed
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
    """Steps between rebuilds of the error's distribution over blocks of pixels (a sum over
    every pixel)."""
    rays_per_pixel: int = 1
    """Rays through each drawn pixel (a square: 1, 4, 9, ...; one per stratum of the pixel),
    whose mean radiance is the pixel's value that the loss compares with the photograph's
    (the batch's rays are shared among fewer pixels). One ray: its colour against the pixel
    favours whichever of leg or background covers more of the pixel, and a thin part whose
    pixels it covers less than half is fitted away. Measured: four kept an antenna at 960 px,
    and lost the legs of a 12 MP capture, whose batches then reach a quarter as many pixels
    (README, "A pixel's rays")."""
    paired: float = 0.0
    """Share of the colour loss taken by pairs of rays (0: one ray a pixel). Above 0, two rays
    go through independent random points of each drawn pixel, and that share of the loss is
    their errors' product (:func:`~reneus_mi.train.losses.paired_l1`), whose expected gradient
    is that of the pixel's mean error: a thin part drawn sharp costs nothing against the
    photograph's blurred pixel, where one ray's loss is least for the blur itself (a leg drawn
    half transparent, its tip faded). The rest is each ray's own L1, whose pull toward the
    blur is also a smoothness prior within a pixel. Not with ``rays_per_pixel`` above 1."""
    blur: float = 0.0
    """Standard deviation, in pixels, of the camera's blur beyond the pixel's area (optics,
    demosaicing, resampling): each ray's point moves by a normal draw of it, so that a pixel's
    rays see what the photograph's pixel saw (0: the pixel's area alone)."""

    def __post_init__(self):
        check_numbers(self, positive=('error_refresh', 'rays_per_pixel'), at_least_zero=('blur',))
        if not 0.0 <= self.error_share <= 1.0:
            raise ReneusError(f'error_share={self.error_share}: expected a share in [0, 1]')
        if round(self.rays_per_pixel ** 0.5) ** 2 != self.rays_per_pixel:
            raise ReneusError(f'rays_per_pixel={self.rays_per_pixel}: expected a square (1, 4, 9, ...): '
                              'one ray per stratum of a k x k grid of the pixel')
        if not 0.0 <= self.paired <= 1.0:
            raise ReneusError(f'paired={self.paired}: expected a share in [0, 1]')
        if self.paired and self.rays_per_pixel > 1:
            raise ReneusError(f'paired with rays_per_pixel={self.rays_per_pixel}: expected one or the '
                              'other (a pair is two rays through the whole pixel)')

    @property
    def rays(self) -> int:
        """Rays through each drawn pixel."""
        return 2 if self.paired > 0.0 else self.rays_per_pixel


#: Bytes per photograph pixel that the sampler holds beyond the dataset, at most (a masked
#: pixel's): its index (4), its colour (3 as 8-bit integers, 6 as half floats) and, for batches
#: drawn by error, its error (4) and a share of its block's prefix sum; the int64 indices it
#: builds them from fit in what loading the dataset freed (``python bench/memory.py``).
BYTES_PER_PIXEL = 16
#: Pixels per block of the error-driven draw (see the module docstring).
ERROR_BLOCK = 64


class PixelSampler:
    """Masked pixels of all views, their colours and their camera rays, on the device."""

    def __init__(self, dataset: Dataset, seed: int = 0, margin: float = 0.0,
                 config: PixelSamplerConfig | None = None):
        """``margin`` widens each view's mask by that fraction of the container's radius in it."""
        self.config = config or PixelSamplerConfig()
        n, h, w = dataset.masks.shape
        masks = dataset.masks if margin == 0.0 else widen(dataset.masks, margin)
        pixels = _by_tile(np.flatnonzero(masks.reshape(-1)), h, w)
        if len(pixels) == 0:
            raise ReneusError(f'{dataset.root}: no view sees the container (all masks are empty)')
        if n * h * w >= 2 ** 32:
            raise ReneusError(f'{dataset.root}: {n} views of {w}x{h} pixels exceed 2^32 pixel indices')
        self.seed, self.height, self.width = seed, h, w
        self.pixels = mi.UInt32(pixels.astype(np.uint32))
        self.n_pixels = len(pixels)
        self.colors, self.color_scale = _compact(dataset.images.reshape(-1, 3)[pixels])
        # Per view: rows of K⁻¹ and of the camera-to-world rotation, and the camera position.
        k_inv = np.linalg.inv(dataset.K)
        self.k_inv = mi.Float(k_inv[:, :2, :].reshape(-1).astype(np.float32))
        self.rotation = mi.Float(dataset.c2w[:, :3, :3].reshape(-1).astype(np.float32))
        self.origin = mi.Float(dataset.c2w[:, :3, 3].reshape(-1).astype(np.float32))
        # Never drawn: -1, i.e. badly fitted (errors are mean absolute colour differences; a
        # negative value is an estimate, its size the weight).
        self.error = dr.full(mi.Float, -1.0, self.n_pixels) if self.config.error_share else None
        self.cdf = _block_cdf(self.error) if self.error is not None else None
        self.drawn: mi.UInt32 | None = None

    def batch(self, step: int, n: int) -> tuple[mi.Ray3f, mi.Color3f]:
        """About ``n`` camera rays through random masked pixels (``config.rays`` each, ray k of
        every pixel in the k-th run of lanes), and the photographs' colours at the pixels."""
        cfg = self.config
        per = cfg.rays
        n = max(n // per, 1)
        rng = mi.PCG32(n, initstate=opaque_seed(step_seed(self.seed, step, PIXELS)))
        slot = rng.next_uint32_bounded(self.n_pixels)
        if self.error is not None:
            if step % cfg.error_refresh == 0:
                self.cdf = _block_cdf(self.error)
            by_error = self._by_error(rng)
            uniform = self.uniform_lanes(n)
            slot = by_error if uniform is None else dr.select(uniform, slot, by_error)
            self.drawn = slot
        index = dr.gather(mi.UInt32, self.pixels, slot)
        side = round(cfg.rays_per_pixel ** 0.5)
        lane = dr.arange(mi.UInt32, n * per)
        k = lane // n % cfg.rays_per_pixel     # the ray's stratum (a pair's share the whole pixel)
        draws = rng if per == 1 else mi.PCG32(n * per,
                                               initstate=opaque_seed(step_seed(self.seed, step, STRATA)))
        u, v = (draws.next_float32(), draws.next_float32()) if cfg.jitter else (0.5, 0.5)
        x, y = (mi.Float(k % side) + u) / side, (mi.Float(k // side) + v) / side
        if cfg.blur > 0.0:
            # Box-Muller: a normal displacement of standard deviation ``blur`` pixels.
            radius = cfg.blur * dr.sqrt(-2.0 * dr.log(1.0 - draws.next_float32()))
            angle = 2.0 * dr.pi * draws.next_float32()
            x, y = x + radius * dr.cos(angle), y + radius * dr.sin(angle)
        if per > 1:
            index = dr.gather(mi.UInt32, index, lane % n)
        return self.rays(index, (x, y)), self.color(slot)

    def uniform(self, step: int, n: int, stream: int) -> tuple[mi.Ray3f, mi.Color3f]:
        """``n`` rays through the centres of masked pixels drawn uniformly from the ``stream`` of
        the step's seeds, and their colours: a batch that leaves the error-driven draw as it is."""
        slot = mi.PCG32(n, initstate=opaque_seed(step_seed(self.seed, step, stream))).next_uint32_bounded(
            self.n_pixels)
        return self.rays(dr.gather(mi.UInt32, self.pixels, slot)), self.color(slot)

    def pixel_mean(self, value):
        """Per drawn pixel, the mean of a per-ray value of the last :meth:`batch` over the
        pixel's rays (the value itself with one ray per pixel)."""
        per = self.config.rays
        if per == 1:
            return value
        total = self.ray(value, 0)
        for k in range(1, per):
            total += self.ray(value, k)
        return total / per

    def ray(self, value, k: int):
        """Per drawn pixel, the per-ray value of the last :meth:`batch` of its k-th ray."""
        n = dr.width(value) // self.config.rays
        return dr.gather(type(value), value, dr.arange(mi.UInt32, n) + k * n)

    def _by_error(self, rng: mi.PCG32) -> mi.UInt32:
        """Slots drawn in proportion to their errors: a block by the prefix sum of the last
        refresh, a pixel within it by the errors now (module docstring)."""
        Float64 = dr.float64_array_t(mi.Float)
        n_blocks = dr.width(self.cdf)
        u = Float64(rng.next_float32()) * dr.gather(Float64, self.cdf, n_blocks - 1)
        block = dr.binary_search(0, n_blocks - 1, lambda k: dr.gather(Float64, self.cdf, k) <= u)
        first = block * ERROR_BLOCK
        size = dr.minimum(ERROR_BLOCK, self.n_pixels - first)

        def error(k):
            return dr.abs(dr.gather(mi.Float, self.error, first + k))
        k, total = dr.while_loop((mi.UInt32(0), mi.Float(0.0)), lambda k, t: k < size,
                                 lambda k, t: (k + 1, t + error(k)))
        target = rng.next_float32() * total
        k, below = dr.while_loop((mi.UInt32(0), mi.Float(0.0)),
                                 lambda k, b: (k + 1 < size) & (b + error(k) <= target),
                                 lambda k, b: (k + 1, b + error(k)))
        return first + k

    def uniform_lanes(self, n: int) -> mi.Bool | None:
        """Which of a batch's ``n`` pixels are drawn uniformly (None: all of them, or none)."""
        if self.error is None or self.config.error_share == 1.0:
            return None
        return mi.Float(dr.arange(mi.UInt32, n)) < dr.opaque(mi.Float, (1.0 - self.config.error_share) * n)

    def uniform_rays(self) -> mi.Bool | None:
        """Which rays of the last :meth:`batch` go through its uniformly drawn pixels (None: all
        of them, or none)."""
        n = dr.width(self.drawn) if self.drawn is not None else 0
        lanes = self.uniform_lanes(n)
        return lanes if lanes is None else self.per_ray(lanes)

    def per_ray(self, value):
        """A per-pixel value of the last :meth:`batch` for each of its rays."""
        per = self.config.rays
        if per == 1:
            return value
        n = dr.width(value)
        return dr.gather(type(value), value, dr.arange(mi.UInt32, n * per) % n)

    def record(self, color: mi.Color3f, target: mi.Color3f) -> None:
        """The colour error of the batch just drawn, per pixel, for the next draws by error; the
        pixels of each drawn one's block never drawn themselves take it as their estimate."""
        if self.error is None:
            return
        error = dr.mean(dr.abs(dr.detach(color) - target), axis=0)
        lane = dr.arange(mi.UInt32, dr.width(self.drawn) * ERROR_BLOCK)
        ray = lane // ERROR_BLOCK
        drawn = dr.gather(mi.UInt32, self.drawn, ray)
        mate = drawn - drawn % ERROR_BLOCK + lane % ERROR_BLOCK
        valid = mate < self.n_pixels
        unseen = valid & (dr.gather(mi.Float, self.error, mate, valid) < 0.0)
        dr.scatter(self.error, -dr.gather(mi.Float, error, ray), mate, unseen)
        dr.eval(self.error)     # the drawn pixels' own errors over any estimate of them
        dr.scatter(self.error, error, self.drawn)

    def state(self) -> dict[str, np.ndarray]:
        """What a checkpoint keeps of the sampler."""
        if self.error is None:
            return {}
        return {'error': np.asarray(self.error, np.float32), 'block_cdf': np.asarray(self.cdf, np.float64)}

    def load(self, state: dict[str, np.ndarray], where: str) -> None:
        if self.error is None:
            return
        if 'error' not in state or len(state['error']) != self.n_pixels or 'block_cdf' not in state:
            raise ReneusError(f'{where}: no pixel errors for the {self.n_pixels} pixels of this dataset; '
                              'expected the checkpoint of a run with train.pixels.error_share > 0 on it '
                              '(made by this version of reneus-mi)')
        self.error = mi.Float(state['error'])
        self.cdf = dr.float64_array_t(mi.Float)(state['block_cdf'])

    def view(self, view: int, stride: int = 1) -> mi.UInt32:
        """Flat indices of every ``stride``-th pixel of a view, row by row."""
        ys, xs = np.mgrid[0:self.height:stride, 0:self.width:stride]
        return mi.UInt32(((view * self.height + ys) * self.width + xs).reshape(-1).astype(np.uint32))

    def color(self, slot: mi.UInt32) -> mi.Color3f:
        """The photographs' colours at masked pixels (by slot: their place among the masked)."""
        stored = type(self.colors)
        return mi.Color3f(*[mi.Float(dr.gather(stored, self.colors, 3 * slot + c)) * self.color_scale
                            for c in range(3)])

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


#: Side of the square tiles that the masked pixels are ordered by (ERROR_BLOCK of them: a
#: block of the error-driven draw is a tile of the photograph where the mask is whole).
TILE = 8


def _by_tile(pixels: np.ndarray, height: int, width: int) -> np.ndarray:
    """Flat pixel indices (view, y, x) ordered tile by tile (TILE x TILE), row by row within."""
    view, rest = np.divmod(pixels, height * width)
    y, x = np.divmod(rest, width)
    return pixels[np.lexsort((x, y % TILE, x // TILE, y // TILE, view))]


def _block_cdf(error: mi.Float):
    """The inclusive prefix sum (float64) of the errors' sums over blocks of :data:`ERROR_BLOCK`:
    block b is drawn where u lies in [cdf[b-1], cdf[b])."""
    sums = dr.float64_array_t(mi.Float)(dr.block_reduce(dr.ReduceOp.Add, dr.abs(error), ERROR_BLOCK))
    cdf = dr.prefix_reduce(dr.ReduceOp.Add, sums, exclusive=False)
    dr.eval(cdf)
    return cdf


def _compact(colors: np.ndarray):
    """(M,3) colours as the device holds them, flat, and the scale to [0, 1]: 8-bit integers
    as they are, 16-bit ones as half floats, float32 (a dataset made in memory) as it is."""
    if colors.dtype == np.uint8:
        return dr.uint8_array_t(mi.Float)(colors.reshape(-1)), 1.0 / 255.0
    if colors.dtype == np.uint16:
        half = (colors.reshape(-1) / np.float32(65535.0)).astype(np.float16)
        return dr.float16_array_t(mi.Float)(half), 1.0
    return mi.Float(colors.reshape(-1).astype(np.float32, copy=False)), 1.0


def widen(masks: np.ndarray, margin: float) -> np.ndarray:
    """Masks grown by ``margin`` times the radius of a disc of the same area, view by view."""
    out = masks.copy()
    for v, mask in enumerate(masks):
        radius = np.sqrt(mask.sum() / np.pi)
        if radius > 0:
            out[v] = distance_transform_edt(~mask) <= margin * radius
    return out
