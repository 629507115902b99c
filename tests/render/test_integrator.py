"""The reneus integrator against Mitsuba's own path tracer, and its XML interface.

Both integrators see the same scene (reference.py): a glass block (IOR 1.45)
holding a sphere in ambient light 0.8. For ``path`` the sphere is an area
emitter behind a black BSDF; for ``reneus`` it is the analytic SDF with the
same radiance and a sharpness so high that the NeuS weights make it opaque.
Both are evaluated along the same pixel-centre rays, ``path`` with 8192
samples per ray, so the only differences are path-tracing noise (standard
error ~5e-4 on average) and the discretisation of the volume rendering.
"""
import dataclasses

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from reference import glass_scene, path_reference, path_scene, pixel_rays, reneus_pixels, reneus_scene
from reneus_mi.plugins import reneus as plugin
from reneus_mi.utils.errors import user_message

RES = 24
SPP = 8192
#: Mean |reneus - path| over the pixels, linear radiance. Measured 0.0006 when
#: right; IOR 1.3 gives 0.033, Fresnel 0.5/0.5 0.071, no reflections 0.017.
MEAN_TOL = 0.003
#: 99th percentile of the per-pixel error (edge pixels of the box and sphere).
P99_TOL = 0.02


@pytest.fixture(scope='module', params=[1, 2], ids=['D1', 'D2'])
def reference(request):
    depth = request.param
    mean, stderr = path_reference(path_scene(RES, max_depth=depth + 1), SPP)
    return depth, mean, stderr


def errors(image, mean):
    d = np.abs(image - mean)
    return d.mean(), np.percentile(d, 99)


def test_matches_path_tracer(reference):
    depth, mean, _ = reference
    mean_err, p99 = errors(reneus_pixels(reneus_scene(RES, max_depth=depth, terminal='black')), mean)
    assert mean_err < MEAN_TOL and p99 < P99_TOL, (mean_err, p99)


def _no_reflection(self, surroundings, rays, hit, T, lanes, reflect, depth=0):
    return ORIGINAL_INTERFACE(self, surroundings, rays, hit, T, lanes, False, depth)


def _half_fresnel(d, n, eta):
    R, d_r, d_t = ORIGINAL_OPTICS(d, n, eta)
    return dr.select(R < 1.0, 0.5, R), d_r, d_t


ORIGINAL_INTERFACE = plugin.ReNeuSIntegrator._interface
ORIGINAL_OPTICS = plugin.interface


@pytest.mark.parametrize('broken', ['ior_1.3', 'fresnel_half', 'no_reflection'])
def test_comparison_has_teeth(reference, broken, monkeypatch):
    depth, mean, _ = reference
    ior = 1.3 if broken == 'ior_1.3' else 1.45
    if broken == 'fresnel_half':
        monkeypatch.setattr(plugin, 'interface', _half_fresnel)
    if broken == 'no_reflection':
        monkeypatch.setattr(plugin.ReNeuSIntegrator, '_interface', _no_reflection)
    mean_err, p99 = errors(reneus_pixels(reneus_scene(RES, ior=ior, max_depth=depth, terminal='black')), mean)
    assert mean_err > 2 * MEAN_TOL, (broken, mean_err)


@pytest.fixture(scope='module', params=[1, 2], ids=['D1', 'D2'])
def board_reference(request):
    """``path`` on the scene with a printed board under the block (reference.board)."""
    depth = request.param
    mean, _ = path_reference(path_scene(RES, max_depth=depth + 1, with_board=True), SPP)
    scene = reneus_scene(RES, max_depth=depth, terminal='black', with_board=True)
    glass = np.array(scene.integrator().render_rays(scene, pixel_rays(scene)).mask)
    return depth, mean, glass


def test_board_under_the_block_matches_path_tracer(board_reference):
    # Rays leaving the glass (through its bottom, or reflected down) meet the board and take its
    # emission, as path does. Measured at D1 / D2: mean 0.0005 / 0.0005 over the image,
    # 0.0016 / 0.0018 over the glass (0.0077 / 0.054 with the board taken as ambient).
    depth, mean, glass = board_reference
    image = reneus_pixels(reneus_scene(RES, max_depth=depth, terminal='black', with_board=True))
    mean_err, p99 = errors(image, mean)
    assert mean_err < MEAN_TOL and p99 < P99_TOL, (mean_err, p99)
    assert np.abs(image - mean)[glass].mean() < MEAN_TOL


def test_board_comparison_has_teeth(board_reference, monkeypatch):
    # Without the board lookup (C_out wherever a ray leaves the glass) the glass's pixels fail.
    from reneus_mi.render.surroundings import Surroundings
    depth, mean, glass = board_reference
    monkeypatch.setattr(Surroundings, 'outside', lambda self, o, d, active=True, lanes=None: self.ambient(d, lanes))
    image = reneus_pixels(reneus_scene(RES, max_depth=depth, terminal='black', with_board=True))
    assert np.abs(image - mean)[glass].mean() > 2 * MEAN_TOL


def test_ambient_terminal_is_closer_to_the_converged_image():
    # The full light transport (path tracer, 16 bounces) against D_re = 2:
    # taking the ambient beyond the last segment errs far less than dropping it.
    converged, _ = path_reference(path_scene(RES, max_depth=16), 2048)
    ambient, _ = errors(reneus_pixels(reneus_scene(RES, max_depth=2)), converged)
    black, _ = errors(reneus_pixels(reneus_scene(RES, max_depth=2, terminal='black')), converged)
    assert ambient < 0.5 * black, (ambient, black)


def test_trace_terminal_follows_the_glass_to_the_board():
    # Over a board, rays left at D_re = 2 inside the glass are mostly on their way to the board
    # by total internal reflection: 'trace' follows them there, 'ambient' takes C_out straight
    # on. Against the full transport (path, 16 bounces), over the glass's pixels: measured trace
    # 0.0052 (what it drops: the sphere beyond the tree), ambient 0.038, black 0.28.
    converged, _ = path_reference(path_scene(RES, max_depth=16, with_board=True), 2048)
    scene = reneus_scene(RES, max_depth=2, with_board=True)
    glass = np.array(scene.integrator().render_rays(scene, pixel_rays(scene)).mask)
    trace = np.abs(reneus_pixels(scene) - converged)[glass].mean()
    ambient = np.abs(reneus_pixels(reneus_scene(RES, max_depth=2, terminal='ambient', with_board=True))
                     - converged)[glass].mean()
    assert trace < 0.01 and trace < 0.25 * ambient, (trace, ambient)


def test_depth_zero_sees_only_the_first_segment():
    # D_re = 0: the camera ray's own segment. It is outside the glass, so the
    # image is the ambient where the ray misses the block and black where it hits.
    scene = reneus_scene(RES, max_depth=0, terminal='black')
    image = reneus_pixels(scene)
    mask = np.array(scene.integrator().render_rays(scene, _rays(scene)).mask)
    assert np.allclose(image[~mask], 0.8, atol=1e-6)
    assert np.allclose(image[mask], 0.0, atol=1e-6)
    assert 0.2 < mask.mean() < 0.8


def _rays(scene):
    from reference import pixel_rays
    return pixel_rays(scene)


def test_aovs_and_gamma():
    # One sample per pixel and one seed: both renders trace the same rays.
    scene = reneus_scene(8, aovs=True, gamma=2.2)
    image = np.array(mi.render(scene, spp=1))
    assert image.shape == (8, 8, 3 + len(plugin.AOV_NAMES))
    linear = np.array(mi.render(reneus_scene(8, gamma=1.0), spp=1))
    assert np.allclose(image[..., :3], np.maximum(linear, 1e-6) ** (1 / 2.2), atol=1e-4)
    mask = image[..., 3]
    assert set(np.unique(mask)) == {0.0, 1.0}
    assert np.allclose(linear[mask == 0], 0.8)
    # Where the sphere is seen the inside segments are opaque: sparsity ≥ 1 - T ≈ 1.
    assert image[..., 4].max() > 0.99


def test_baseline_modes_are_farther_from_the_truth():
    # Against the converged path tracer (16 bounces): the paper's renderer at
    # D_re = 2 errs least, NeuS+ (one refraction, no Fresnel) more, NeuS
    # (glass ignored) most. Measured: 0.0014, 0.0054, 0.017.
    converged, _ = path_reference(path_scene(RES, max_depth=16), 2048)
    err = {mode: errors(reneus_pixels(reneus_scene(RES, mode=mode)), converged)[0]
           for mode in ('reneus', 'neus_plus', 'neus')}
    assert 2 * err['reneus'] < err['neus_plus'] and 2 * err['neus_plus'] < err['neus'], err


XML = '''<scene version="3.0.0">
  <integrator type="reneus" id="field">
    <string name="mode" value="{mode}"/>
    <integer name="max_depth" value="{depth}"/>
    <integer name="n_coarse" value="16"/>
    <integer name="n_fine" value="8"/>
    <integer name="n_upsample_steps" value="2"/>
    <float name="upsample_s" value="32"/>
    <float name="gamma" value="2.2"/>
    <boolean name="aovs" value="true"/>
    <string name="field" value="sphere"/>
    <float name="field_radius" value="0.25"/>
    <rgb name="field_color" value="0.2, 0.5, 0.7"/>
    <point name="field_center" x="0.1" y="0" z="0"/>
    <float name="field_scale" value="1.5"/>
    <string name="dataset" value="some/folder"/>
  </integrator>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/></film>
  </sensor>
  <emitter type="constant"><rgb name="radiance" value="0.8"/></emitter>
  {shape}
</scene>'''
GLASS = '<shape type="cube"><bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf></shape>'


def test_xml_with_every_parameter():
    scene = mi.load_string(XML.format(mode='reneus', depth=3, shape=GLASS))
    it = scene.integrator()
    render, sampler = it.model.render, it.model.sampler
    assert (render.mode, render.max_depth, render.gamma, render.aovs) == ('reneus', 3, 2.2, True)
    assert (sampler.n_coarse, sampler.n_fine, sampler.n_upsample_steps, sampler.upsample_s) == (16, 8, 2, 32.0)
    assert it.dataset == 'some/folder'
    assert it.frame.center == (0.1, 0.0, 0.0) and it.frame.scale == 1.5
    assert it.field.cfg.radius == 0.25 and it.field.cfg.color == pytest.approx((0.2, 0.5, 0.7))
    assert float(it.bind(scene).container_eta[0]) == pytest.approx(1.5 / 1.000277, rel=1e-5)


@pytest.mark.parametrize('mode, depth, shape, message', [
    ('reneus', 2, '', 'no shape'),
    ('reneus', 2, '<shape type="cube"><bsdf type="diffuse"/></shape>', "smooth 'dielectric'"),
    ('reneus', 2, '<shape type="rectangle"><emitter type="area"/></shape>', 'no shape with a dielectric BSDF'),
    ('reneus', -1, GLASS, 'max_depth=-1'),
    ('reneus_pp', 2, GLASS, "mode='reneus_pp'"),
])
def test_bad_xml_gives_clear_errors(mode, depth, shape, message):
    xml = XML.format(mode=mode, depth=depth, shape=shape)
    with pytest.raises((RuntimeError, ValueError)) as e:
        scene = mi.load_string(xml)
        mi.render(scene, spp=1)
    assert message in user_message(e.value)


def test_unknown_parameter_is_named():
    xml = XML.format(mode='reneus', depth=2, shape=GLASS).replace(
        '<integer name="max_depth"', '<integer name="max_detph" value="2"/><integer name="max_depth"')
    with pytest.raises(RuntimeError, match="unknown parameter.*'max_detph'"):
        mi.load_string(xml)


@pytest.mark.parametrize('key', ['integrator.sdf.weights', 'integrator.color.weights',
                                 'integrator.variance'])
def test_render_gradients_match_finite_differences(key):
    # mi.render with params= gives the field's weights their gradients. With
    # coarse samples only, the sample positions do not move with the weights,
    # so autodiff and central differences compute the same derivative. The
    # differences are rendered with the seed mi.render gives its gradient pass
    # (it decorrelates it from the primal one), so both see the same pixels.
    from reneus_mi.fields.neus import NeuSField
    scene = reneus_scene(6, **TINY_NEUS)
    assert isinstance(scene.integrator().field, NeuSField)
    params = mi.traverse(scene)
    assert {'integrator.sdf.weights', 'integrator.color.weights', 'integrator.variance'} <= set(params.keys())
    w = mi.Float(np.random.default_rng(0).uniform(0.5, 1.5, 6 * 6 * 3).astype(np.float32))

    def loss(image):
        return dr.sum(image.array * w)

    dr.enable_grad(params[key])
    params.update()
    dr.backward(loss(mi.render(scene, params=params, spp=1, seed=3)))
    seed_grad = int(mi.sample_tea_32(3, 1)[0])
    grad, value = np.array(dr.grad(params[key])), np.array(params[key])
    # The entries with the largest effect, where FD is well above float noise.
    for i in np.argsort(-np.abs(grad))[:3]:
        h = 1e-3 * max(1.0, abs(value[i]))
        f = []
        for sign in (1, -1):
            v = value.copy()
            v[i] += sign * h
            params[key] = type(params[key])(v)
            params.update()
            f.append(float(loss(mi.render(scene, spp=1, seed=seed_grad))[0]))
        params[key] = type(params[key])(value)
        params.update()
        fd = (f[0] - f[1]) / (2 * h)
        assert fd == pytest.approx(grad[i], rel=0.05, abs=2e-3), (key, i, fd, grad[i])


def test_trace_gradient_of_sharpness_matches_finite_differences():
    from reference import pixel_rays
    scene = reneus_scene(6, **TINY_NEUS)
    it = scene.integrator()
    ray = pixel_rays(scene)
    w = np.random.default_rng(0).uniform(0.5, 1.5, (3, 36)).astype(np.float32)

    def loss(variance):
        it.field.set_params({'variance': variance})
        return dr.sum(dr.sum(it.render_rays(scene, ray).color * mi.Color3f(*w)))

    v = mi.Float(0.25)
    dr.enable_grad(v)
    dr.backward(loss(v))
    h = 1e-3
    with dr.suspend_grad():
        fd = (float(loss(mi.Float(0.25 + h))[0]) - float(loss(mi.Float(0.25 - h))[0])) / (2 * h)
    assert fd == pytest.approx(float(dr.grad(v)[0]), rel=0.02)


#: The tiny preset's field, coarse samples only (see test_render_gradients_match_finite_differences).
TINY_NEUS = dict(preset='tiny', field='neus', n_coarse=24, n_fine=0, gamma=2.2, field_init_variance=0.25)


def test_untrained_field_renders_a_sphere():
    # In neus mode a camera ray has one segment, so 'sparsity' is its opacity
    # 1 - T: the untrained field must cover exactly the pixels whose ray meets
    # the sphere of radius init_radius. The SIREN field starts as that sphere
    # at any width; SAL's softplus initialisation is a sphere only on average
    # over random weights (fields/test_fields.py checks it that way).
    from reference import pixel_rays
    scene = reneus_scene(32, **{**TINY_NEUS, 'mode': 'neus', 'field_init_radius': 0.35,
                                'field_activation': 'sine', 'field_init_variance': 0.5})
    ray = pixel_rays(scene)
    opacity = np.array(scene.integrator().render_rays(scene, ray).sparsity)
    o, d = np.array(ray.o).T, np.array(ray.d).T
    b = (o * d).sum(axis=1)
    hits = b * b - ((o * o).sum(axis=1) - 0.35 ** 2) > 0
    covered = opacity > 0.5
    iou = (covered & hits).sum() / (covered | hits).sum()
    assert iou > 0.95, iou
    assert opacity[hits].mean() > 0.9 and opacity[~hits].mean() < 0.1


def test_russian_roulette_is_unbiased():
    # Roulette on branches lighter than 0.5 (every reflection, and refractions
    # behind a half-opaque segment): over many seeds the mean image is the
    # deterministic tree's. Measured: |mean - tree| / SE has a mean of ~0.8 (a
    # normal's is 0.8); dropping the 1/p reweighting gives a mean of ~67.
    from reneus_mi.render.step_state import StepState
    from reference import pixel_rays
    scene = reneus_scene(12, max_depth=3, field_inv_s=30.0)
    it = scene.integrator()
    ray = pixel_rays(scene)
    tree = np.array(it.render_rays(scene, ray).L).T
    it.configure(dataclasses.replace(it.model, render=dataclasses.replace(it.model.render, rr_threshold=0.5)),
                 it.field)
    runs = []
    for seed in range(256):
        it.state = StepState(seed=seed)
        runs.append(np.array(it.render_rays(scene, ray).L).T)
    runs = np.stack(runs)
    mean, se = runs.mean(axis=0), runs.std(axis=0) / np.sqrt(len(runs))
    random = se > 1e-6
    assert random.mean() > 0.3   # the roulette is at work on many pixels
    z = np.abs(mean - tree)[random] / se[random]
    assert z.mean() < 1.2 and np.percentile(z, 99) < 4.0, (z.mean(), np.percentile(z, 99))


def test_partial_update_keeps_the_other_keys():
    scene = glass_scene(preset='tiny')
    field = scene.integrator().field
    params = mi.traverse(scene)
    sdf = np.array(params['field.sdf.weights'])
    params['field.variance'] = mi.Float(0.6)
    params.update()
    assert float(field.inv_s()[0]) == pytest.approx(np.exp(6.0), rel=1e-6)
    assert np.array_equal(np.array(field.params()['sdf.weights']), sdf)
    params['field.sdf.weights'] = mi.Float(sdf * 0.5)
    params.update()
    assert float(field.inv_s()[0]) == pytest.approx(np.exp(6.0), rel=1e-6)
    assert np.allclose(np.array(field.params()['sdf.weights']), sdf * 0.5)


def test_hand_written_adam_loop_moves_the_field():
    """The notebook's loop: gradients reach the field through mi.render, updates land in it."""
    scene = glass_scene(preset='tiny', n_coarse=16, n_fine=0)
    params = mi.traverse(scene)
    keys = [k for k in params.keys() if k.startswith('field.')]
    opt = mi.ad.Adam(lr=1e-2, params={k: params[k] for k in keys})
    params.update(opt)
    before = np.array(scene.integrator().field.params()['color.weights'])
    image = mi.render(scene, params, spp=1, seed=0)
    dr.backward(dr.mean(dr.abs(image - 0.3), axis=None))
    assert all(dr.any(dr.grad(opt[k]) != 0) for k in ('field.color.weights', 'field.sdf.weights'))
    opt.step()
    params.update(opt)
    after = np.array(scene.integrator().field.params()['color.weights'])
    assert np.allclose(after, np.array(opt['field.color.weights']))
    assert np.abs(after - before).max() > 1e-3


@pytest.mark.parametrize('prop, value, message', [
    ('n_coarse', 'many', "n_coarse='many': expected an integer"),
    ('max_depth', 'two', "max_depth='two': expected an integer"),
    ('field_hidden', 2.5, 'field_hidden=2.5: expected an integer'),
    ('preset', 'huge', "preset='huge'; expected one of"),
    ('field_hiden', 16, "unknown parameter(s) 'field_hiden'"),
])
def test_integrator_settings_are_typed_and_named(prop, value, message):
    with pytest.raises(Exception) as e:
        glass_scene(**{prop: value})
    assert message in user_message(e.value)
