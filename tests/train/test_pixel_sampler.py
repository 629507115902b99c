"""The pixel sampler: colours as the photographs hold them, and draws in proportion to error."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from reneus_mi.data import Dataset
from reneus_mi.train.pixel_sampler import ERROR_BLOCK, PixelSampler, PixelSamplerConfig
from reneus_mi.utils.errors import ReneusError


def _dataset(images: np.ndarray, masks: np.ndarray) -> Dataset:
    n, h, w = masks.shape
    K = np.tile(np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1]], np.float64), (n, 1, 1))
    return Dataset(images=images, masks=masks, K=K, c2w=np.tile(np.eye(4), (n, 1, 1)),
                   names=[f'{i}.png' for i in range(n)], root='memory')


def _points_in_pixels(sampler: PixelSampler, ds: Dataset, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Where a batch's rays cross the image plane, relative to their pixels' corners."""
    ray, _ = sampler.batch(0, n)
    d = np.asarray(ray.d).T
    K = ds.K[0]                     # identity cameras: the pixel position is K d
    x = d[:, 0] / d[:, 2] * K[0, 0] + K[0, 2]
    y = d[:, 1] / d[:, 2] * K[1, 1] + K[1, 2]
    h, w = ds.masks.shape[1:]
    rest = np.asarray(sampler.pixels)[np.asarray(sampler.drawn)] % (h * w)
    per = sampler.config.rays
    return x - np.tile(rest % w, per), y - np.tile(rest // w, per)


@pytest.mark.parametrize('dtype, tolerance', [(np.uint8, 0.0), (np.uint16, 2.0 ** -11), (np.float32, 0.0)])
def test_colours_are_the_photographs(dtype, tolerance):
    rng = np.random.default_rng(1)
    masks = rng.random((3, 20, 30)) < 0.4
    top = {np.uint8: 255, np.uint16: 65535, np.float32: 1.0}[dtype]
    values = rng.random((3, 20, 30, 3))
    images = (np.round(values * top) if top != 1.0 else values).astype(dtype)
    sampler = PixelSampler(_dataset(images, masks), config=PixelSamplerConfig(error_share=0.0))
    got = np.asarray(sampler.color(dr.arange(mi.UInt32, sampler.n_pixels))).T
    expected = images.reshape(-1, 3)[np.asarray(sampler.pixels)].astype(np.float64) / top
    assert sorted(np.asarray(sampler.pixels)) == list(np.flatnonzero(masks))
    assert got.shape == expected.shape
    assert np.max(np.abs(got - expected)) <= tolerance + 1e-7


def test_draws_follow_the_errors():
    """Frequencies of error-driven draws against each pixel's share of the errors, with blocks
    of very different sums and a last block shorter than ERROR_BLOCK."""
    rng = np.random.default_rng(2)
    masks = np.zeros((2, 30, 40), bool)
    masks[:, 5:25, 3:37] = True                     # 1360 pixels: 21 blocks and 16 left over
    assert masks.sum() % ERROR_BLOCK != 0
    sampler = PixelSampler(_dataset(np.zeros(masks.shape + (3,), np.uint8), masks), seed=3,
                           config=PixelSamplerConfig(jitter=False, error_share=1.0, error_refresh=10 ** 6))
    error = rng.random(sampler.n_pixels).astype(np.float32) ** 4
    error[:ERROR_BLOCK] = 0.0                                          # a block never drawn
    error[700] = 40.0                                                  # one pixel with a fifth of it all
    error[-1] = 5.0                                                    # the short block's last pixel
    sampler.error = mi.Float(error)
    counts = np.zeros(sampler.n_pixels)
    n = 1 << 17
    for step in range(8):
        sampler.batch(step * 10 ** 6, n)        # refreshed at step 0 only (error_refresh)
        np.add.at(counts, np.asarray(sampler.drawn), 1)
    p = error / error.sum()
    total = counts.sum()
    assert counts[:ERROR_BLOCK].sum() == 0
    for pixel in (700, sampler.n_pixels - 1):
        assert counts[pixel] / total == pytest.approx(p[pixel], rel=0.02)
    # Pixels grouped by their expected count: chi-square over the groups.
    order = np.argsort(p)
    groups = np.array_split(order[p[order] > 0], 40)
    expected = np.array([p[g].sum() * total for g in groups])
    seen = np.array([counts[g].sum() for g in groups])
    chi2 = float(np.sum((seen - expected) ** 2 / expected))
    assert chi2 < 80.0, chi2        # 39 degrees of freedom: p < 0.001 beyond 73


def test_a_block_is_a_tile_whose_unseen_pixels_take_the_last_error_drawn():
    """The masked pixels are ordered tile by tile (a block of the draw: 8 x 8 pixels where the
    mask is whole); a pixel's error, once recorded, is the estimate of the tile's pixels never
    drawn, and theirs alone is kept for the drawn."""
    masks = np.ones((1, 16, 16), bool)
    sampler = PixelSampler(_dataset(np.zeros(masks.shape + (3,), np.uint8), masks),
                           config=PixelSamplerConfig(jitter=False, error_share=1.0))
    y, x = np.divmod(np.asarray(sampler.pixels)[:ERROR_BLOCK], 16)
    assert y.max() - y.min() == 7 and x.max() - x.min() == 7          # the top-left tile
    sampler.drawn = mi.UInt32([3, 70])
    sampler.record(mi.Color3f([0.5, 0.2], [0.5, 0.2], [0.5, 0.2]), mi.Color3f(0.0))
    error = np.asarray(sampler.error)
    assert error[3] == pytest.approx(0.5) and error[70] == pytest.approx(0.2)
    assert np.allclose(np.delete(error[:ERROR_BLOCK], 3), -0.5)
    assert np.allclose(np.delete(error[ERROR_BLOCK:2 * ERROR_BLOCK], 70 - ERROR_BLOCK), -0.2)
    assert np.all(error[2 * ERROR_BLOCK:] == -1.0)
    sampler.drawn = mi.UInt32([5])
    sampler.record(mi.Color3f(0.1), mi.Color3f(0.0))
    error = np.asarray(sampler.error)
    assert error[3] == pytest.approx(0.5) and error[5] == pytest.approx(0.1) and error[6] == pytest.approx(-0.1)


def test_draws_within_a_block_follow_errors_now():
    """Between refreshes a block is drawn by the errors it had; a pixel in it by those it has."""
    masks = np.ones((1, 8, 2 * ERROR_BLOCK // 8), bool)
    sampler = PixelSampler(_dataset(np.zeros(masks.shape + (3,), np.uint8), masks), seed=4,
                           config=PixelSamplerConfig(jitter=False, error_share=1.0, error_refresh=10 ** 6))
    # Dr.Jit's CPU backend copies a NumPy array into a variable asynchronously: each array
    # here is left as it was given.
    sampler.error = mi.Float(np.ones(2 * ERROR_BLOCK, np.float32))
    sampler.batch(0, 16)                                # the blocks' sums: equal
    error = np.ones(2 * ERROR_BLOCK, np.float32)
    error[:ERROR_BLOCK] = 0.0
    error[5] = 1.0                                      # the first block now has one pixel in error
    sampler.error = mi.Float(error)
    sampler.batch(1, 1 << 14)
    drawn = np.asarray(sampler.drawn)
    first = drawn < ERROR_BLOCK
    assert first.mean() == pytest.approx(0.5, abs=0.02)
    assert np.all(drawn[first] == 5)


def test_a_pixels_rays_fill_its_strata_and_its_value_is_their_mean():
    """Four rays per pixel: ray k of each drawn pixel in the k-th quarter of the lanes, through
    a random point of the k-th cell of the pixel's 2 x 2 grid, and the pixel's value the mean of
    its rays'; a batch of n rays shares them among n / 4 pixels."""
    masks = np.zeros((2, 12, 16), bool)
    masks[:, 2:10, 3:13] = True
    ds = _dataset(np.zeros(masks.shape + (3,), np.uint8), masks)
    sampler = PixelSampler(ds, seed=5, config=PixelSamplerConfig(rays_per_pixel=4))
    n = 4096
    u, v = _points_in_pixels(sampler, ds, n)
    assert len(u) == n and len(np.asarray(sampler.drawn)) == n // 4
    assert np.all((u > -1e-4) & (u < 1 + 1e-4) & (v > -1e-4) & (v < 1 + 1e-4))
    k = np.repeat(np.arange(4), n // 4)
    assert np.all(np.floor(np.clip(u, 0, 0.9999) * 2) == k % 2)
    assert np.all(np.floor(np.clip(v, 0, 0.9999) * 2) == k // 2)
    # Within its cell a ray goes anywhere: the cells' points spread over them.
    assert np.std(u * 2 - k % 2) == pytest.approx(np.sqrt(1 / 12), rel=0.1)
    values = np.random.default_rng(0).random((3, n)).astype(np.float32)
    mean = np.asarray(sampler.pixel_mean(mi.Color3f(values)))
    assert np.allclose(mean, values.reshape(3, 4, n // 4).mean(axis=1), atol=1e-6)


def test_a_pairs_rays_go_through_independent_points_of_the_whole_pixel():
    """Paired rays: both of a pixel's anywhere in it (uniform over the pixel, uncorrelated); a
    batch of n rays is n / 2 pixels."""
    masks = np.zeros((1, 12, 16), bool)
    masks[:, 2:10, 3:13] = True
    ds = _dataset(np.zeros(masks.shape + (3,), np.uint8), masks)
    sampler = PixelSampler(ds, seed=7, config=PixelSamplerConfig(paired=1.0))
    n = 1 << 14
    u, v = _points_in_pixels(sampler, ds, n)
    assert len(u) == n and len(np.asarray(sampler.drawn)) == n // 2
    for t in (u, v):
        assert np.all((t > -1e-4) & (t < 1 + 1e-4))
        first, second = t[:n // 2], t[n // 2:]
        for half in (first, second):
            assert np.var(half) == pytest.approx(1 / 12, rel=0.05)
        assert abs(np.corrcoef(first, second)[0, 1]) < 0.03


def test_paired_is_a_share_and_excludes_strata():
    with pytest.raises(ReneusError, match=r'paired=1.5: expected a share in \[0, 1\]'):
        PixelSamplerConfig(paired=1.5)
    with pytest.raises(ReneusError, match='paired with rays_per_pixel=4: expected one or the other'):
        PixelSamplerConfig(paired=1.0, rays_per_pixel=4)


def test_blur_spreads_the_rays_as_the_camera_does():
    """With a blur of 0.7 pixels a ray's point is the pixel's uniform one plus a normal one:
    its variance 1/12 + 0.49 along each axis, and as many on either side of the pixel."""
    masks = np.zeros((1, 30, 30), bool)
    masks[:, 10:20, 10:20] = True
    ds = _dataset(np.zeros(masks.shape + (3,), np.uint8), masks)
    sampler = PixelSampler(ds, seed=6, config=PixelSamplerConfig(blur=0.7))
    u, v = _points_in_pixels(sampler, ds, 1 << 16)
    for t in (u, v):
        assert np.var(t) == pytest.approx(1 / 12 + 0.49, rel=0.03)
        assert np.mean(t) == pytest.approx(0.5, abs=0.01)
        assert np.mean(t < 0) == pytest.approx(np.mean(t > 1), abs=0.01)


def test_rays_per_pixel_is_a_square():
    with pytest.raises(ReneusError, match='rays_per_pixel=3: expected a square'):
        PixelSamplerConfig(rays_per_pixel=3)
