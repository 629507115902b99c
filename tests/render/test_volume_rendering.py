"""Volume rendering of segments: analytic hits, a dense reference quadrature, gradients."""
import numpy as np
import pytest

import reneus_mi  # noqa: F401  (selects the variant)
import drjit as dr
import mitsuba as mi

from reneus_mi.fields import Field, SphereField
from reneus_mi.render.ray_samplers import SamplerConfig
from reneus_mi.render.volume_rendering import volume_render

COLOR = (0.2, 0.5, 0.8)


class ParamSphere(Field):
    """g = k (|x - c| - r), c = (0, c_y, 0), radiance varying with x and n.

    r, s, colour, k and c_y are differentiable; c_y moves the normals at fixed x.

    It keeps the base class's finite-difference gradient, as a neural field does.
    """

    def __init__(self, radius=0.5, inv_s=20.0, color=COLOR, scale=1.0, center_y=0.0):
        self.p = {'radius': mi.Float(radius), 'inv_s': mi.Float(inv_s), 'color': mi.Color3f(color),
                  'scale': mi.Float(scale), 'center_y': mi.Float(center_y)}

    def geometry(self, x):
        c = mi.Vector3f(0.0, self.p['center_y'], 0.0)
        return (dr.norm(mi.Vector3f(x) - c) - self.p['radius']) * self.p['scale'], []

    def radiance(self, x, v, n, feature):
        return self.p['color'] * (0.6 + 0.3 * n.y + 0.1 * x.z)

    def inv_s(self):
        return self.p['inv_s']


def _rays(y, z, x0=-1.5, t_near=0.5, t_far=2.5):
    """Rays along +x from (x0, y, z), as arrays and as Dr.Jit segments."""
    n = len(y)
    o = mi.Point3f(mi.Float(np.full(n, x0)), mi.Float(y), mi.Float(z))
    d = mi.Vector3f(mi.Float(np.ones(n)), mi.Float(np.zeros(n)), mi.Float(np.zeros(n)))
    return o, d, dr.full(mi.Float, t_near, n), dr.full(mi.Float, t_far, n)


def _reference(y, z, radius, inv_s, scale=1.0, x0=-1.5, t_near=0.5, t_far=2.5, n=8192):
    """Dense quadrature of NeuS's continuous model for ParamSphere, in float64.

    α_i = max(1 - Φ_s(g(t_{i+1})) / Φ_s(g(t_i)), 0) with the exact g at the section
    ends: the discrete form of T(t) = exp(-∫ρ) (NeuS Eq. 9, ReNeuS Eq. 5) without
    NeuS's ε and without its linearised end values.
    """
    t = np.linspace(t_near, t_far, n + 1)
    x = np.stack(np.broadcast_arrays(x0 + t[None, :], y[:, None], z[:, None]), axis=-1)
    phi = 1.0 / (1.0 + np.exp(-inv_s * scale * (np.linalg.norm(x, axis=-1) - radius)))
    alpha = np.clip(1.0 - phi[:, 1:] / phi[:, :-1], 0.0, 1.0)
    trans = np.cumprod(1.0 - alpha, axis=1)
    w = alpha * np.concatenate([np.ones((len(y), 1)), trans[:, :-1]], axis=1)
    xm = 0.5 * (x[:, 1:] + x[:, :-1])
    nm = xm / np.linalg.norm(xm, axis=-1, keepdims=True)
    shade = 0.6 + 0.3 * nm[..., 1] + 0.1 * xm[..., 2]
    color = (w * shade).sum(axis=1)[:, None] * np.array(COLOR)
    return color, trans[:, -1], (w * 0.5 * (t[1:] + t[:-1])).sum(axis=1)


def test_sharp_sphere_hits_and_misses():
    field = SphereField(radius=0.5, inv_s=2000.0, color=COLOR)
    rng = np.random.default_rng(0)
    y = np.concatenate([rng.uniform(-0.45, 0.45, 12), [0.55, -0.7, 0.9, 0.6]])
    z = np.concatenate([rng.uniform(-0.2, 0.2, 12), [0.0, 0.1, -0.3, 0.6]])
    hit = y ** 2 + z ** 2 < 0.25
    o, d, t_near, t_far = _rays(y, z)
    for jitter in (None, mi.Float(rng.uniform(0, 1, len(y)))):
        r = volume_render(field, SamplerConfig(n_coarse=32, n_fine=32).setup(), o, d, t_near, t_far, jitter=jitter)
        trans, color = np.asarray(r.transmittance), np.asarray(r.color).T
        depth, normal = np.asarray(r.depth), np.asarray(r.normal).T
        assert np.all(np.asarray(r.n_samples) == 65)
        assert np.all(trans[hit] < 1e-4)
        np.testing.assert_allclose(color[hit], np.tile(COLOR, (hit.sum(), 1)), atol=1e-3)
        # Hit distance from x0 = -1.5 to the sphere: 1.5 - sqrt(r² - y² - z²).
        t_hit = 1.5 - np.sqrt(0.25 - y[hit] ** 2 - z[hit] ** 2)
        np.testing.assert_allclose(depth[hit], t_hit, atol=5e-4)  # 1/s = 5e-4
        n_hit = np.stack([-1.5 + t_hit, y[hit], z[hit]], axis=1) / 0.5
        assert np.all(np.sum(normal[hit] * n_hit, axis=1) > 0.995)
        # NeuS's ε leaves 1e-5 opacity per empty section: 65 sections cost < 1e-3.
        assert np.all(trans[~hit] > 0.999)
        assert np.all(np.abs(color[~hit]) < 1e-3)
        np.testing.assert_allclose(np.asarray(r.eikonal), 0.0, atol=1e-6)


def test_soft_field_matches_dense_quadrature():
    rng = np.random.default_rng(1)
    y, z = rng.uniform(-0.8, 0.8, 24), rng.uniform(-0.5, 0.5, 24)
    color, trans, depth = _reference(y, z, 0.45, 20.0)
    r = volume_render(ParamSphere(radius=0.45, inv_s=20.0), SamplerConfig().setup(), *_rays(y, z))  # 64 + 64 samples
    # Quadrature error (observed <= 1.5e-3) plus NeuS's ε: 1e-5 of opacity per
    # section, 129 sections (1024 uniform sections would be 1e-2 off).
    np.testing.assert_allclose(np.asarray(r.transmittance), trans, atol=4e-3)
    np.testing.assert_allclose(np.asarray(r.color).T, color, atol=2.5e-3)
    np.testing.assert_allclose(np.asarray(r.depth), depth, atol=5e-3)


def test_eikonal_counts_each_sample():
    y = np.array([0.05, 0.3, 0.9])
    sampler = SamplerConfig(n_coarse=8, n_fine=8, n_upsample_steps=2).setup()
    r = volume_render(ParamSphere(scale=1.5), sampler, *_rays(y, 0 * y))
    # |∇g| = 1.5 everywhere (the stencil is exact up to O(h²) curvature terms).
    np.testing.assert_allclose(np.asarray(r.eikonal), np.asarray(r.n_samples) * 0.25, rtol=1e-3)


def _loss(field, rays, n_fine):
    r = volume_render(field, SamplerConfig(n_coarse=32, n_fine=n_fine, n_upsample_steps=2).setup(), *rays)
    return dr.sum(r.color.x + 0.5 * r.color.y + 0.25 * r.color.z + 0.3 * r.transmittance
                  + 0.2 * r.depth + 0.1 * r.normal.y + 0.05 * r.eikonal)


def test_gradients_match_finite_differences():
    rng = np.random.default_rng(2)
    rays = _rays(rng.uniform(-0.7, 0.7, 16), rng.uniform(-0.7, 0.7, 16))
    base = {'radius': 0.5, 'inv_s': 20.0, 'scale': 1.2, 'color': COLOR, 'center_y': 0.1}
    field = ParamSphere(**base)
    for value in field.p.values():
        dr.enable_grad(value)
    # Coarse samples only: their positions do not depend on the field, so the
    # finite difference and the gradient (which ignores sample motion) agree.
    dr.backward(_loss(field, rays, n_fine=0))
    for key, h in (('radius', 2e-3), ('inv_s', 0.2), ('scale', 2e-3), ('color', 2e-3), ('center_y', 2e-3)):
        grad = dr.grad(field.p[key])
        grad = grad.y if key == 'color' else grad

        def loss_at(delta):
            values = dict(base)
            values[key] = (COLOR[0], COLOR[1] + delta, COLOR[2]) if key == 'color' else base[key] + delta
            return _loss(ParamSphere(**values), rays, n_fine=0)[0]

        fd = (loss_at(h) - loss_at(-h)) / (2 * h)
        assert grad[0] == pytest.approx(fd, rel=2e-3, abs=1e-5), key


def test_degenerate_inputs():
    field = SphereField(radius=0.5)
    empty = volume_render(field, SamplerConfig().setup(), mi.Point3f(), mi.Vector3f(), mi.Float(), mi.Float())
    assert dr.width(empty.color) == 0 and dr.width(empty.transmittance) == 0
    # Zero-length segments inside the object absorb nothing.
    o, d, _, _ = _rays(np.zeros(2), np.zeros(2), x0=0.0)
    r = volume_render(field, SamplerConfig(n_coarse=4, n_fine=0).setup(), o, d, mi.Float(0.1, 0.2), mi.Float(0.1, 0.1))
    np.testing.assert_allclose(np.asarray(r.transmittance), 1.0)
    np.testing.assert_allclose(np.asarray(r.color), 0.0)

    o, d, t_near, t_far = _rays(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match='t_far'):
        volume_render(field, SamplerConfig().setup(), o, d, t_near, mi.Float(1.0, 2.0))
    with pytest.raises(ValueError, match='cos_anneal_ratio'):
        volume_render(field, SamplerConfig().setup(), o, d, t_near, t_far, cos_anneal_ratio=1.5)


def test_reverse_gathers_reuse_their_kernels_at_any_width():
    """The reverse mode of a gather is a scatter-add into the source's gradient, and the ray
    tree's arrays (live rays, inside segments) change width every step. Dr.Jit's LLVM
    backend, left to choose, expanded such targets per thread with the width compiled in:
    refining runs compiled a kernel at almost every step (reneus_mi.utils.variant switches the
    expansion off). The kernels must be the same ones whatever the width, and the adjoints
    summed right."""
    def kernels(width):
        src = dr.opaque(mi.Float, 1.0, width)
        dr.enable_grad(src)
        lanes = dr.arange(mi.UInt32, 4096)
        y = dr.gather(mi.Float, src, lanes % dr.opaque(mi.UInt32, width))
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory):
            dr.backward(dr.sum(y * y))
            grad = dr.grad(src)
            dr.eval(grad)
            hashes = {k['hash'] for k in dr.kernel_history() if k.get('type') == dr.KernelType.JIT}
        assert float(grad[0]) == 2.0 * len(range(0, 4096, width))   # lanes that read element 0
        return hashes

    first = kernels(1001)
    assert first and all(kernels(width) == first for width in (1003, 1007))


def test_nearest_is_where_a_segment_passes_closest_to_the_surface():
    """The ``reach`` term's input: a ray that misses the sphere reports the SDF where it passes
    nearest (its distance to the sphere, to within the sections' spacing), with the gradient
    of the SDF there; a ray that hits reports a negative value."""
    y = np.array([0.0, 0.3, 0.6, 0.75, 0.9])
    z = np.zeros_like(y)
    field = ParamSphere(radius=0.5, inv_s=20.0, scale=1.2)
    for value in field.p.values():
        dr.enable_grad(value)
    r = volume_render(field, SamplerConfig(n_coarse=64, n_fine=0).setup(), *_rays(y, z))
    nearest = np.asarray(r.nearest)
    miss = y > 0.5
    # 64 sections over [0.5, 2.5]: a midpoint lies within 1/64 of the closest point, where the
    # distance grows by at most (1/64)^2 / (2 y).
    np.testing.assert_allclose(nearest[miss], 1.2 * (y[miss] - 0.5), atol=1.2 * (1 / 64) ** 2 / 1.2)
    assert np.all(nearest[~miss] < 0.0)
    # The sphere's own colour at its nearest point (the ray's x = 0 there: shade 0.6 + 0.3 n_y).
    np.testing.assert_allclose(np.asarray(r.nearest_color).T[miss],
                               np.outer(0.6 + 0.3 * 1.0, COLOR).repeat(miss.sum(), 0), atol=2e-3)
    dr.backward(dr.sum(r.nearest))
    # g = k (|x| - r): dg/dr = -k at every point, one point per ray.
    assert dr.grad(field.p['radius'])[0] == pytest.approx(-1.2 * len(y), rel=1e-5)


def test_nearest_moves_the_field_not_the_rays():
    """Where the glass is refined the rays carry its gradient: the reach term must not pull the
    rays toward the surface (it biased a refined IOR by 0.0115 against 1.45 when it did)."""
    y = np.array([0.6, 0.75, 0.9])
    o, d, t_near, t_far = _rays(y, 0 * y)
    lift = mi.Float(0.0)
    dr.enable_grad(lift)
    field = ParamSphere(radius=0.5, inv_s=20.0)
    dr.enable_grad(field.p['radius'])
    r = volume_render(field, SamplerConfig(n_coarse=64, n_fine=0).setup(), mi.Point3f(o.x, o.y + lift, o.z),
                      d, t_near, t_far)
    dr.backward(dr.sum(r.nearest))
    # Without the correction d/d(lift) = 3 (each miss ray's distance grows with its y).
    assert abs(dr.grad(lift)[0]) < 1e-4
    assert dr.grad(field.p['radius'])[0] == pytest.approx(-3.0, rel=1e-5)
