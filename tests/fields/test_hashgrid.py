"""The hash-grid field: initial sphere, analytic gradient, parameter gradients,
coarse-to-fine schedule, files and bad input.

One tiny configuration (4 levels, 2^12 entries, 16 wide) throughout, so that
the file compiles a handful of kernels. Losses weight every point differently:
with a uniform incoming gradient (e.g. ``dr.sum`` straight on a network
output), Dr.Jit 1.5's cooperative-vector backward on LLVM credits a bias with
one lane's gradient instead of the sum over lanes.
"""
import functools
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import reference
from reneus_mi.fields import FIELD_KINDS, HashGridField, load_field
from reneus_mi.render.ray_samplers import neus_alpha

TINY = dict(n_levels=4, features_per_level=2, log2_hashmap_size=12, base_resolution=4,
            finest_resolution=32, hidden=16, n_features=4, color_hidden=16, color_layers=1,
            multires_view=1, levels_start=2, level_steps=10)


#: Points well inside the grid (radius 0.9 of its unit sphere).
ball_points = functools.partial(reference.ball_points, r_max=0.9)


def trained_looking(field, amplitude=0.3):
    """Perturb every parameter (deterministically) so that no gradient is trivially zero."""
    values = {k: v + amplitude * dr.sin(dr.arange(type(v), dr.width(v)) * 1.7)
              for k, v in field.params().items() if k != 'variance'}
    dr.eval(values)
    field.set_params(values)
    return field


def outputs(field, n=64, seed=5):
    x, _ = ball_points(n, seed)
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(3, n))
    v /= np.linalg.norm(v, axis=0)
    g, grad, feature = field.gradient(x)
    rgb = field.radiance(x, mi.Vector3f(v.astype(np.float32)), dr.normalize(grad), feature)
    return [np.asarray(a, dtype=np.float64) for a in (g, grad, *feature, rgb)]


def test_untrained_field_is_the_sphere():
    field = HashGridField(init_radius=0.4, seed=1, **TINY)
    x, r = ball_points(2000, seed=1)
    g, grad, _ = field.gradient(x)
    # Residual head at 1e-3 of its fan-in scale: measured max 3e-4.
    assert np.abs(np.asarray(g) - (r - 0.4)).max() < 2e-3
    # On the sphere itself: the zero level set.
    on, _ = ball_points(500, seed=2, r_min=0.4, r_max=0.4)
    assert np.abs(np.asarray(field.sdf(on))).max() < 2e-3
    normal = np.asarray(x, dtype=np.float64) / r
    assert np.abs(np.asarray(grad, dtype=np.float64) - normal).max() < 2e-2


def test_encoding_matches_drjit_hashgrid():
    """The hand-written trilinear lookup is drjit.nn.HashGridEncoding's, value for value."""
    field = trained_looking(HashGridField(**TINY))
    field.set_step(10 ** 6)  # every level open: no mask
    x, _ = ball_points(300, seed=3)
    u = x * 0.5 + 0.5
    reference = field.encoding([u.x, u.y, u.z])
    ours, _ = field._encode(u, jacobian=False)
    for a, b in zip(reference, ours):
        assert np.array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize('activation', ['relu', 'softplus'])
def test_analytic_gradient_matches_autodiff(activation):
    field = trained_looking(HashGridField(activation=activation, layers=2, **TINY))
    x, _ = ball_points(256, seed=4, r_min=0.05)
    g, grad, _ = field.gradient(x)
    xa = mi.Point3f(x)
    dr.enable_grad(xa)
    dr.backward(field.sdf(xa))
    reference = np.asarray(dr.grad(xa), dtype=np.float64)
    # |∇g| reaches ~40 with these weights: float32 agreement.
    assert np.abs(np.asarray(grad, dtype=np.float64) - reference).max() < 1e-4 * np.abs(reference).max()
    assert np.array_equal(np.asarray(g), np.asarray(field.sdf(x)))


def test_parameter_gradients_match_finite_differences():
    """d/dθ of a NeuS-shaped loss: alpha of sections around x (through g, ∇g and
    s), an Eikonal term, and the colour, for the table, both MLPs and the variance."""
    field = trained_looking(HashGridField(**TINY), amplitude=0.1)
    field.set_step(10 ** 6)
    n = 48
    # Sections through the initial surface, rays heading inwards: α in (0, 1).
    x, r = ball_points(n, seed=6, r_min=0.45, r_max=0.55)
    rng = np.random.default_rng(6)
    d = -np.asarray(x, dtype=np.float64) / r + 0.5 * rng.normal(size=(3, n))
    d /= np.linalg.norm(d, axis=0)
    d = mi.Vector3f(d.astype(np.float32))
    w = mi.Float(rng.uniform(0.5, 1.5, n).astype(np.float32))

    def loss():
        g, grad, feature = field.gradient(x)
        half = dr.dot(d, grad) * 0.05
        alpha = neus_alpha(g - half, g + half, field.inv_s())
        rgb = field.radiance(x, d, dr.normalize(grad), feature)
        eikonal = dr.square(dr.norm(grad) - 1.0)
        return dr.sum(w * (alpha + 0.01 * eikonal + rgb.x + 0.5 * rgb.y - rgb.z))

    params = field.params()
    for value in params.values():
        dr.enable_grad(value)
    dr.backward(loss())
    grads = {k: np.asarray(dr.grad(v), dtype=np.float64) for k, v in params.items()}
    for value in params.values():
        dr.disable_grad(value)

    rng = np.random.default_rng(0)
    eps = {'sdf.grid': 3e-3, 'sdf.weights': 1e-3, 'color.weights': 1e-3, 'variance': 1e-3}
    for key, grad in grads.items():
        assert np.abs(grad).max() > 0, key
        picks = np.concatenate([np.argsort(-np.abs(grad))[:3],
                                rng.choice(np.flatnonzero(grad), min(3, np.count_nonzero(grad)), replace=False)])
        base = np.asarray(params[key]).copy()
        for i in np.unique(picks):
            values = []
            for sign in (1.0, -1.0):
                p = base.copy()
                p[i] += sign * eps[key]
                field.set_params({key: type(params[key])(p)})
                values.append(float(loss()[0]))
            fd = (values[0] - values[1]) / (2 * eps[key])
            assert abs(fd - grad[i]) < 2e-2 + 2e-2 * abs(grad[i]), (key, i, fd, grad[i])
        field.set_params({key: type(params[key])(base)})


def test_set_step_opens_levels_without_recompiling():
    field = trained_looking(HashGridField(**TINY))
    cfg = field.cfg
    enc = field.encoding
    x, _ = ball_points(64, seed=7)

    def level_sdf():
        return np.asarray(field.sdf(x), dtype=np.float64)

    def kernels(step):
        """Values at ``step`` and the hashes of the kernels that computed them."""
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory):
            dr.kernel_history()
            field.set_step(step)
            values = level_sdf()
            return values, {k['hash'] for k in dr.kernel_history([dr.KernelType.JIT])}

    assert cfg.open_levels(0) == 2
    field.set_step(0)
    unchanged = level_sdf()
    # Change the table of level 2 only: closed at step 0, open from step 10.
    table = np.asarray(field.params()['sdf.grid']).copy()
    lo, hi = (enc.level_offset(i) * cfg.features_per_level for i in (2, 3))
    table[lo:hi] += 0.5
    field.set_params({'sdf.grid': mi.Float(table)})
    before, kernels_before = kernels(0)
    assert np.array_equal(before, unchanged)
    assert math.isclose(field.fd_step[0], 2.0 / enc._level_scale(1), rel_tol=1e-6)

    opened, kernels_after = kernels(10)
    assert np.abs(opened - before).max() > 1e-3
    # The same kernel, whatever the caches hold: opening a level compiles nothing.
    assert kernels_after == kernels_before
    assert math.isclose(field.fd_step[0], 2.0 / enc._level_scale(2), rel_tol=1e-6)
    # Later steps open the rest, and no more than there are.
    field.set_step(10 ** 6)
    assert field.cfg.open_levels(10 ** 6) == cfg.n_levels == 4
    assert math.isclose(field.fd_step[0], 2.0 / enc._level_scale(3), rel_tol=1e-6)


def test_numerical_gradient_follows_the_finest_open_level():
    field = trained_looking(HashGridField(gradient='numerical', **TINY))
    x, _ = ball_points(64, seed=8)
    field.set_step(0)
    _, coarse, _ = field.gradient(x)
    h = float(field.fd_step[0])
    # The base class's stencil with that step, evaluated by hand.
    g = [np.asarray(field.sdf(x + mi.Vector3f(*e) * h), dtype=np.float64)
         for e in ((1, -1, -1), (-1, -1, 1), (-1, 1, -1), (1, 1, 1))]
    e = np.array(((1, -1, -1), (-1, -1, 1), (-1, 1, -1), (1, 1, 1)), dtype=np.float64)
    manual = sum(e[k][:, None] * g[k] for k in range(4)) / (4 * h)
    assert np.allclose(np.asarray(coarse, dtype=np.float64), manual, rtol=1e-4, atol=1e-3)


def test_save_load_round_trip(tmp_path):
    field = trained_looking(HashGridField(seed=3, **TINY))
    field.set_step(15)
    field.save(tmp_path / 'f.npz')
    loaded = load_field(tmp_path / 'f.npz')
    assert isinstance(loaded, HashGridField) and loaded.config() == field.config()
    assert loaded.cfg.step == 15
    for key, value in field.params().items():
        assert np.array_equal(np.asarray(loaded.params()[key]), np.asarray(value))
    for a, b in zip(outputs(field), outputs(loaded)):
        assert np.array_equal(a, b)
    assert np.array_equal(np.asarray(loaded.inv_s()), np.asarray(field.inv_s()))


def test_registration_and_param_groups():
    assert FIELD_KINDS['HashGridField'] is HashGridField
    field = HashGridField(grid_lr_scale=10.0, **TINY)
    assert set(field.params()) == {'sdf.grid', 'sdf.weights', 'color.weights', 'variance'}
    groups = {g.name: g for g in field.param_groups(1e-3)}
    assert groups['field.grid'].keys == ('sdf.grid',) and groups['field.grid'].learning_rate == 1e-2
    assert set(groups['field'].keys) == {'sdf.weights', 'color.weights', 'variance'}
    assert groups['field'].learning_rate == 1e-3 and all(g.start == 0 for g in groups.values())
    assert dr.width(field.params()['sdf.grid']) == field.encoding.n_params


@pytest.mark.parametrize('options, message', [
    (dict(n_levels=0), 'n_levels=0; expected an integer > 0'),
    (dict(features_per_level=3), 'features_per_level=3; expected one of 2, 4, 8'),
    (dict(log2_hashmap_size=30), 'log2_hashmap_size=30'),
    (dict(base_resolution=64, finest_resolution=32), 'finest_resolution=32; expected at least'),
    (dict(gradient='exact'), "gradient='exact'"),
    (dict(activation='tanh'), "activation='tanh'"),
    (dict(init_radius=1.5), 'init_radius=1.5'),
    (dict(width=3), r"unknown option\(s\) \['width'\]"),
])
def test_bad_config(options, message):
    with pytest.raises(ValueError, match=message) as info:
        HashGridField(**{**TINY, **options})
    assert '\n' not in str(info.value)


def test_bad_parameter_and_feature_widths():
    field = HashGridField(**TINY)
    with pytest.raises(ValueError, match="'sdf.grid' given 3 values"):
        field.set_params({'sdf.grid': mi.Float(1, 2, 3)})
    x = mi.Point3f(0.0, 0.0, 0.5)
    with pytest.raises(ValueError, match='1 feature channels, expected 4'):
        field.radiance(x, mi.Vector3f(0, 0, 1), mi.Vector3f(0, 0, 1), [mi.Float(0)])


def test_half_precision_field_follows_the_float32_one(tmp_path):
    """dtype='float16' is what CUDA runs (cooperative vectors pack only half
    there); on the CPU it must agree with float32 to half precision."""
    half = HashGridField(dtype='float16', seed=2, **TINY)
    full = HashGridField(dtype='float32', seed=2, **TINY)
    assert dr.is_half_v(half.params()['sdf.grid']) and dr.is_half_v(half.params()['sdf.weights'])
    assert not dr.is_half_v(half.params()['variance'])
    for a, b in zip(outputs(half), outputs(full)):
        assert np.allclose(a, b, atol=1e-2, rtol=1e-2)
    half.save(tmp_path / 'h.npz')
    loaded = load_field(tmp_path / 'h.npz')
    for a, b in zip(outputs(half), outputs(loaded)):
        assert np.array_equal(a, b)
