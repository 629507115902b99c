"""Empty-space skipping: the occupancy grid never culls the surface, and skipping changes nothing."""
import numpy as np
import pytest

import reneus_mi  # noqa: F401  (selects the variant)
import drjit as dr
import mitsuba as mi

from reneus_mi.fields import BoxField, Field, SphereField, TorusField
from reneus_mi.render.occupancy import OccupancyGrid
from reneus_mi.render.ray_samplers import SamplerConfig
from reneus_mi.render.volume_rendering import volume_render

FIELDS = {
    'sphere': lambda s: SphereField(radius=0.3, inv_s=s, center=(0.2, 0.1, -0.1)),
    'box': lambda s: BoxField(half_size=(0.3, 0.2, 0.1), inv_s=s, center=(-0.1, 0.1, 0.2)),
    'torus': lambda s: TorusField(major=0.4, minor=0.12, inv_s=s, center=(0.15, -0.1, 0.05)),
}


class StretchedSphere(Field):
    """g = k (|x| - r): the zero set of a sphere, but |∇g| = k (a field that is not yet a distance)."""

    def __init__(self, k, radius=0.5, inv_s=1e6):
        self.k, self.radius, self.s = k, radius, inv_s

    def geometry(self, x):
        return self.k * (dr.norm(mi.Vector3f(x)) - self.radius), []

    def inv_s(self):
        return mi.Float(self.s)


class CountingField(Field):
    """Wraps a field and counts the points at which its SDF is evaluated."""

    def __init__(self, inner):
        self.inner, self.evaluations = inner, 0

    def geometry(self, x):
        self.evaluations += dr.width(x)
        return self.inner.geometry(x)

    def gradient(self, x):
        self.evaluations += dr.width(x)
        return self.inner.gradient(x)

    def radiance(self, x, v, n, feature):
        return self.inner.radiance(x, v, n, feature)

    def inv_s(self):
        return self.inner.inv_s()


def _surface_cells(field, res, sub=5):
    """Cells in which a dense lattice (``sub``^3 points, corners included) finds both signs of g."""
    cell = 2.0 / res
    u = np.linspace(0.0, 1.0, sub)
    off = np.stack(np.meshgrid(u, u, u, indexing='ij'), axis=-1).reshape(-1, 3) * cell
    idx = np.arange(res ** 3)
    corner = np.stack([idx % res, (idx // res) % res, idx // res ** 2], axis=1) * cell - 1.0
    x = (corner[:, None, :] + off[None]).reshape(-1, 3)
    g = np.asarray(field.sdf(mi.Point3f(*[mi.Float(v) for v in x.T]))).reshape(res ** 3, -1)
    return (g.min(axis=1) <= 0.0) & (g.max(axis=1) >= 0.0)


def _grid(field, res, lipschitz, margin):
    grid = OccupancyGrid(res, field.bound, lipschitz=lipschitz, margin=margin)
    grid.update(field)
    return np.asarray(grid.occupied)


@pytest.mark.parametrize('name', FIELDS)
def test_no_cell_with_a_zero_crossing_is_culled(name):
    # An exact SDF is 1-Lipschitz: the bare bound (factor 1, no margin, s so
    # sharp that the density band vanishes) already covers the surface.
    field = FIELDS[name](1e6)
    surface = _surface_cells(field, 16)
    bare = _grid(field, 16, 1.0, 0.0)
    assert surface.sum() > 20 and np.all(bare[surface])
    # ... and it is not everything: most of the cube is found empty.
    assert bare.mean() < 0.3


def test_lipschitz_safety_factor_covers_a_field_that_is_not_a_distance():
    field = StretchedSphere(k=1.8)
    surface = _surface_cells(field, 16)
    # Trusting |∇g| <= 1 loses surface cells of a field whose gradient is 1.8 ...
    assert not np.all(_grid(field, 16, 1.0, 0.0)[surface])
    # ... the default safety factor (2) keeps them all.
    cfg = SamplerConfig()
    assert np.all(_grid(field, 16, cfg.occupancy_lipschitz, 0.0)[surface])


def _segments(field, n, seed):
    """Random segments inside the unit sphere, half of them aimed at the object."""
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3))
    o *= rng.uniform(0.3, 0.95, (n, 1)) / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.normal(size=(n, 3))
    aim = np.array(field.cfg.center) + rng.normal(0.0, 0.1, (n, 3)) - o
    d[: n // 2] = aim[: n // 2]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    b = np.sum(o * d, axis=1)
    t_far = -b + np.sqrt(b * b - np.sum(o * o, axis=1) + 1.0)
    return o, d, t_far


def _dr(o, d, t_far):
    n = len(t_far)
    return (mi.Point3f(*[mi.Float(v) for v in o.T]), mi.Vector3f(*[mi.Float(v) for v in d.T]),
            dr.zeros(mi.Float, n), mi.Float(t_far))


def test_span_matches_a_dense_march_through_a_random_grid():
    res, n = 8, 400
    grid = OccupancyGrid(res, 1.0, lipschitz=1.0, margin=0.0)
    rng = np.random.default_rng(4)
    occupied = rng.uniform(size=res ** 3) < 0.03
    grid.occupied = mi.Bool(occupied)
    # Segments inside the cube, some of them starting or ending outside it.
    o = rng.uniform(-1.2, 1.2, (n, 3))
    d = rng.normal(size=(n, 3))
    d[:50, 1:] = 0.0  # axis-aligned: divisions by zero in the march
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_far = rng.uniform(0.2, 2.5, n)
    first, last = (np.asarray(v) for v in grid.span(*_dr(o, d, np.zeros(n))[:2], mi.Float(np.zeros(n)),
                                                     mi.Float(t_far)))
    t = np.linspace(0.0, 1.0, 20001)[None, :] * t_far[:, None]
    x = o[:, None] + t[..., None] * d[:, None]
    cell = np.floor((x + 1.0) * res / 2.0).astype(int)
    outside = np.any((cell < 0) | (cell >= res), axis=-1)
    cell = np.clip(cell, 0, res - 1)
    hit = occupied[(cell[..., 2] * res + cell[..., 1]) * res + cell[..., 0]] | outside
    step = t_far / 20000
    for r in range(n):
        if not hit[r].any():
            assert first[r] > last[r], r
            continue
        ts = t[r][hit[r]]
        assert abs(first[r] - ts.min()) <= step[r] + 1e-5 and abs(last[r] - ts.max()) <= step[r] + 1e-5, r


@pytest.mark.parametrize('name', FIELDS)
def test_span_holds_every_point_of_the_segment_inside_the_surface(name):
    field = FIELDS[name](1e6)
    o, d, t_far = _segments(field, 300, 1)
    sampler = SamplerConfig(occupancy_resolution=16, occupancy_lipschitz=1.0, occupancy_margin=0.0).setup()
    sampler.update(field, 0)
    first, last = (np.asarray(v) for v in sampler.grid.span(*_dr(o, d, t_far)))
    t = np.linspace(0.0, 1.0, 2001)[None, :] * t_far[:, None]
    x = o[:, None] + t[..., None] * d[:, None]
    g = np.asarray(field.sdf(mi.Point3f(*[mi.Float(v) for v in x.reshape(-1, 3).T]))).reshape(t.shape)
    solid = g <= 0.0
    assert np.all((t >= first[:, None]) & (t <= last[:, None]) | ~solid)
    # Segments with no point in the solid are mostly dropped (first > last).
    empty = ~solid.any(axis=1)
    assert np.mean(first[empty] > last[empty]) > 0.5


@pytest.mark.parametrize('name', FIELDS)
def test_rendering_with_the_grid_equals_rendering_without(name):
    field = FIELDS[name](1000.0)
    o, d, t_far = _segments(field, 400, 2)
    segs = _dr(o, d, t_far)
    jitter = mi.Float(np.random.default_rng(3).uniform(0.0, 1.0, len(t_far)))
    cfg = dict(n_coarse=32, n_fine=16, n_upsample_steps=2)
    plain = volume_render(field, SamplerConfig(**cfg).setup(), *segs, jitter=jitter)
    grid = volume_render(field, SamplerConfig(**cfg, occupancy_resolution=32).setup(), *segs, jitter=jitter)
    kept = np.asarray(grid.n_samples) > 0
    assert 0.2 < kept.mean() < 0.9
    # Rays that graze the surface are quadrature-limited with or without the
    # grid (the samples sit elsewhere): compare the rays that start outside
    # and meet the surface, if at all, clearly.
    t = np.linspace(0.0, 1.0, 513)[None, :] * t_far[:, None]
    g = np.asarray(field.sdf(mi.Point3f(*[mi.Float(v) for v in (o[:, None] + t[..., None] * d[:, None])
                                          .reshape(-1, 3).T]))).reshape(t.shape)
    clear = (g[:, 0] > 0.03) & (np.abs(g.min(axis=1)) > 0.03)
    assert clear.mean() > 0.8 and (g.min(axis=1)[clear] < 0).mean() > 0.15
    # What remains is NeuS's ε: every section has opacity >= 1e-5, so a skipped
    # segment (T = 1) differs from a sampled empty one by 1 - (1 - 1e-5)^48.
    leak = 1.0 - (1.0 - 1e-5) ** (cfg['n_coarse'] + cfg['n_fine'])
    # The depth (Σ w t, t <= 2) carries the leak twice over, and the hit moves
    # within the sharpness's width 1/s as the samples do.
    for key, tol in (('transmittance', leak + 1e-4), ('color', leak + 1e-4), ('depth', 2 * leak + 2e-3)):
        a, b = np.asarray(getattr(plain, key)), np.asarray(getattr(grid, key))
        err = np.abs(a - b).reshape(-1, len(t_far)).max(axis=0)
        assert np.all(err[clear] <= tol), key


def test_empty_segments_cost_no_field_evaluation():
    field = CountingField(SphereField(radius=0.2, inv_s=1000.0))
    sampler = SamplerConfig(n_coarse=8, n_fine=8, n_upsample_steps=2, occupancy_resolution=16).setup()
    sampler.update(field, 0)
    field.evaluations = 0
    # Two segments that pass far from the sphere, one through it.
    o = mi.Point3f(mi.Float(-0.9, -0.9, -0.9), mi.Float(0.8, -0.8, 0.0), mi.Float(0.3, -0.3, 0.05))
    d = mi.Vector3f(mi.Float(1.0, 1.0, 1.0), mi.Float(0.0), mi.Float(0.0))
    r = volume_render(field, sampler, o, d, dr.zeros(mi.Float, 3), dr.full(mi.Float, 1.8, 3))
    np.testing.assert_array_equal(np.asarray(r.n_samples), [0, 0, 17])
    np.testing.assert_array_equal(np.asarray(r.transmittance)[:2], 1.0)
    assert np.asarray(r.transmittance)[2] < 1e-3
    # The sampler's 8 + 2 coarse and 2 x 4 fine SDF values and the 17 sections, for one segment only.
    assert field.evaluations == 10 + 2 * 4 + 17
    field.evaluations = 0
    volume_render(field, sampler, mi.Point3f(-0.9, 0.8, 0.3), mi.Vector3f(1.0, 0.0, 0.0), mi.Float(0.0), mi.Float(1.8))
    assert field.evaluations == 0


def test_update_refreshes_the_grid_every_k_steps():
    field = SphereField(radius=0.2, inv_s=1000.0)
    sampler = SamplerConfig(occupancy_resolution=16, occupancy_update_every=4).setup()
    sampler.update(field, 0)
    before = np.asarray(sampler.grid.occupied).copy()
    field.cfg.radius = 0.6
    sampler.update(field, 3)
    np.testing.assert_array_equal(np.asarray(sampler.grid.occupied), before)
    sampler.update(field, 4)
    assert np.asarray(sampler.grid.occupied).sum() > 2 * before.sum()
    # Without a grid, update does nothing.
    plain = SamplerConfig().setup()
    plain.update(field, 0)
    assert plain.grid is None


@pytest.mark.parametrize('kwargs, message', [
    ({'n_coarse': 0}, 'n_coarse=0'),
    ({'n_fine': -1}, 'n_fine=-1'),
    ({'n_fine': 10, 'n_upsample_steps': 4}, 'n_fine=10 is not a multiple of n_upsample_steps=4'),
    ({'upsample_s': 0.0}, 'upsample_s=0.0'),
    ({'occupancy_resolution': 2.5}, 'occupancy_resolution=2.5'),
    ({'occupancy_lipschitz': -1}, 'occupancy_lipschitz=-1'),
    ({'occupancy_margin': -0.1}, 'occupancy_margin=-0.1'),
    ({'occupancy_update_every': 0}, 'occupancy_update_every=0'),
])
def test_config_errors_name_the_field(kwargs, message):
    with pytest.raises(ValueError, match=message) as e:
        SamplerConfig(**kwargs)
    assert '\n' not in str(e.value)


def test_update_reuses_its_kernel_as_the_sharpness_grows():
    """The threshold follows s: as data, or every update (each 16 steps) compiled anew."""
    def hashes(inv_s):
        grid = OccupancyGrid(32, 1.0, lipschitz=1.5, margin=0.0)
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory):
            grid.update(SphereField(radius=0.3, inv_s=inv_s))
            return {k['hash'] for k in dr.kernel_history() if k.get('type') == dr.KernelType.JIT}

    first = hashes(20.0)
    assert first and hashes(50.0) == first == hashes(400.0)
