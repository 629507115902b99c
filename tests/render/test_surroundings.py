"""The surroundings the integrator owns: the light's SH basis, the container's pose, the render
derivatives with respect to each refinable quantity against central differences, and smooth
containers against Mitsuba's path tracer."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
import trimesh

from reference import (AMBIENT, derivatives_agree, path_reference, path_scene, pixel_rays, render_derivatives,
                       reneus_pixels, reneus_scene)
from reneus_mi.config import RefineConfig
from reneus_mi.geometry.shapes import container_mesh, write_container
from reneus_mi.render.light import Light, fibonacci_directions, sh_basis
from reneus_mi.render.pose import ContainerPose
from reneus_mi.render.step_state import StepState


def _constant(value=AMBIENT):
    return mi.load_dict({'type': 'constant', 'radiance': {'type': 'rgb', 'value': value}})


def _directions(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return mi.Vector3f(*(mi.Float(d[:, i].astype(np.float32)) for i in range(3))), d


@pytest.mark.parametrize('kind', ['ambient', 'sh'])
def test_light_starts_as_the_scenes_constant_emitter(kind):
    d, _ = _directions(100)
    L = np.array(Light(kind, _constant()).eval(d))
    assert np.abs(L - AMBIENT).max() < 1e-4


def test_sh_light_reproduces_a_room_of_order_two():
    # A room brighter above and on one side: within SH order 2, so exactly representable.
    def room(d):
        return 0.6 + 0.3 * d[:, 2] + 0.1 * d[:, 0] * d[:, 1] + 0.05 * d[:, 0]
    light = Light('sh', _constant())
    q = fibonacci_directions(8192)
    Y = np.array([np.broadcast_to(np.array(y), (len(q),)) for y in sh_basis(
        mi.Vector3f(*(mi.Float(q[:, i].astype(np.float32)) for i in range(3))))])
    c = (4 * np.pi / len(q)) * Y @ room(q)
    light.coefficients = mi.Float(np.repeat(c[:, None], 3, axis=1).ravel().astype(np.float32))
    d, dn = _directions(200, seed=1)
    assert np.abs(np.array(light.eval(d))[0] - room(dn)).max() < 2e-3


def _pose(t=(0.02, -0.01, 0.03), r=(0.1, -0.2, 0.05), s=(0.01, -0.02, 0.03)):
    pose = ContainerPose((0.1, 0.2, -0.1))
    pose.translation, pose.rotation, pose.log_scale = mi.Float(t), mi.Float(r), mi.Float(s)
    return pose


def test_pose_maps_rays_and_normals_consistently():
    pose = _pose()
    _, p = _directions(50, seed=2)
    x = mi.Point3f(*(mi.Float(p[:, i].astype(np.float32)) for i in range(3)))
    d, _ = _directions(50, seed=3)
    # A world ray taken into the container's frame meets the same points at the same t.
    o_c, d_c = pose.to_container(x, d)
    for t in (0.0, 0.7):
        back = np.array(pose.to_world(o_c + t * d_c))
        assert np.abs(back - np.array(x + t * d)).max() < 1e-5
    # Normals stay perpendicular to transformed tangents.
    n, _ = _directions(50, seed=4)
    tangent = dr.normalize(dr.cross(n, d))
    moved = np.array(pose.to_world(x + 1e-2 * tangent)) - np.array(pose.to_world(x))
    assert np.abs(np.sum(moved * np.array(pose.normal_to_world(n)), axis=0)).max() < 1e-5
    M = pose.matrix()
    assert np.abs((M[:3, :3] @ p.T).T + M[:3, 3] - np.array(pose.to_world(x)).T).max() < 1e-5


def _refinable_scene(res=8, **settings):
    scene = reneus_scene(res, **{'field_inv_s': 60.0, **settings})
    scene.integrator().configure(refine=RefineConfig(pose=True, light='ambient', absorption=True))
    scene.integrator().bind(scene)
    return scene


def test_identity_pose_renders_the_scene_as_loaded():
    plain = reneus_pixels(reneus_scene(24))
    posed = reneus_pixels(_refinable_scene(24, field_inv_s=4000.0))
    assert np.abs(plain - posed).mean() < 1e-6 and np.abs(plain - posed).max() < 2e-3


@pytest.mark.parametrize('key, i, with_board', [
    ('container.eta', 0, False), ('container.translation', 0, False), ('container.translation', 1, False),
    ('container.rotation', 2, False), ('container.log_scale', 0, False), ('light.radiance', 1, False),
    ('container.eta', 0, True), ('container.translation', 0, True),
    ('board.shading', 4 * 8 + 4, True), ('board.shading', 3 * 8 + 4, True)])
def test_render_gradients_of_surroundings_match_finite_differences(key, i, with_board):
    # Interior derivatives, pixel by pixel: the rays keep their pixels, the glass moves under
    # them; the samples of each inside segment follow its ends. Coarse samples only (fine ones
    # are drawn anew where the surface moves, which central differences see and AD does not).
    # With the board under the block, the refracted rays also move over its print.
    # The board's shading on 8 x 8 texels, each under many pixels.
    scene = _refinable_scene(16, max_depth=2, n_fine=0, with_board=with_board, board_texels=8)
    ad, fd = render_derivatives(scene, key, i)
    agree = derivatives_agree(ad, fd)
    assert agree.mean() > (0.95 if with_board else 0.99), (key, i, agree.mean())
    assert np.abs(ad - fd)[agree].sum() < 0.02 * np.abs(fd)[agree].sum(), key
    # A texel's gain moves a pixel by the print's radiance there through the glass (black print: little).
    assert np.abs(fd).max() > (0.03 if key == 'board.shading' else 0.3), (key, np.abs(fd).max())


@pytest.mark.parametrize('key, i', [
    ('container.eta', 0), ('container.translation', 0), ('container.rotation', 2), ('container.log_scale', 1),
    ('light.radiance', 1), ('container.sigma_a', 2), ('board.shading', 4 * 8 + 4)])
def test_refined_quantities_learn_from_the_refining_rays_alone(key, i):
    # StepState.refining: a refined quantity's derivative is the same on the rays it names and
    # none on the others (an error-drawn batch's biased rays); the board's shading, fitted with
    # the field as part of the model, keeps its derivative on every ray. The radiance is the same.
    scene = _refinable_scene(16, max_depth=2, n_fine=0, with_board=True, board_texels=8, sigma_a=(0.1, 0.2, 0.3))
    integrator, ray = scene.integrator(), pixel_rays(scene)
    lanes = dr.arange(mi.UInt32, dr.width(ray.o)) % 3 == 0
    array = integrator.params()[key]
    out = []
    for refining in (None, lanes):
        integrator.begin_step(StepState(refining=refining))
        dr.enable_grad(array)
        dr.set_grad(array, mi.Float(np.eye(dr.width(array), dtype=np.float32)[i]))
        L = integrator.render_rays(scene, ray).L
        dr.forward_to(L)
        out.append((np.array(L), np.array(dr.grad(L))))
        dr.disable_grad(array)
    (L_all, d_all), (L_some, d_some) = out
    keep = np.array(lanes) if key != 'board.shading' else np.ones(dr.width(ray.o), bool)
    assert np.array_equal(L_all, L_some)
    assert np.abs(d_all[:, keep]).max() > 1e-3, key     # the pixels it moves include kept ones
    assert np.array_equal(d_some[:, keep], d_all[:, keep]) and not np.any(d_some[:, ~keep]), key


# ------------------------------------------------------------ smooth glass
#: Mean |reneus - path| (linear) on the rounded block: measured 0.0008 with its shading normals,
#: 0.0045 with the normals of its facets.
SMOOTH_TOL = 0.003


@pytest.fixture(scope='module')
def rounded_block(tmp_path_factory):
    mesh = container_mesh('rounded', (0.55, 0.45, 0.5))
    normals = mesh.vertex_normals.copy()
    rot = trimesh.transformations.rotation_matrix(np.radians(25), [0, 1, 0])
    mesh.apply_transform(rot)
    mesh.vertex_normals = normals @ rot[:3, :3].T
    path = str(tmp_path_factory.mktemp('rounded') / 'rounded.ply')
    write_container(mesh, path, normals=True)
    return path


@pytest.mark.parametrize('pose', [False, True], ids=['as_loaded', 'posed'])
def test_smooth_container_matches_path_tracer(rounded_block, pose):
    # Shading normals bend the light on a tessellated rounded block as in Mitsuba's
    # dielectric; flat facets (the geometric normals) would not (measured below).
    mean, _ = path_reference(path_scene(24, max_depth=3, mesh=rounded_block), 4096)
    scene = reneus_scene(24, mesh=rounded_block, max_depth=2, terminal='black')
    scene.integrator().configure(refine=RefineConfig(pose=pose))
    reneus = reneus_pixels(scene)
    error = np.abs(reneus - mean).mean()
    print(f"mean |reneus - path| {error:.5f}")
    assert error < SMOOTH_TOL


def test_smooth_container_comparison_has_teeth(rounded_block, monkeypatch):
    from reneus_mi.plugins import reneus as plugin
    original = plugin._Hit

    def flat(t, p, n, n_s, valid, group, si):
        return original(t, p, n, n, valid, group, si)
    mean, _ = path_reference(path_scene(24, max_depth=3, mesh=rounded_block), 1024)
    monkeypatch.setattr(plugin, '_Hit', flat)
    reneus = reneus_pixels(reneus_scene(24, mesh=rounded_block, max_depth=2, terminal='black'))
    # The tolerance of test_smooth_container_matches_path_tracer: facets fail it.
    assert np.abs(reneus - mean).mean() > SMOOTH_TOL


@pytest.mark.parametrize('container', ['rounded', 'box8'])
def test_refined_container_file_keeps_its_optics(rounded_block, tmp_path, container):
    """The refined container is written where its pose puts it with the normals light was
    bent by: read back, its shading normals are the posed ones (before: the rounded block
    lost its stored normals)."""
    from reneus_mi.geometry.container import container_shape, shading_normals
    from reneus_mi.geometry.mesh import write_mesh
    from reneus_mi.render.surroundings import Surroundings
    path = rounded_block
    if container == 'box8':
        path = str(tmp_path / 'box8.ply')
        trimesh.creation.box(extents=(1.1, 0.9, 1.0)).export(path)
    shape = container_shape(path)
    surroundings = Surroundings(None, [shape], _constant(), pose=True, pivot=(0.1, 0.2, -0.1))
    surroundings.pose = _pose()
    written = str(tmp_path / 'refined.ply')
    write_mesh(surroundings.posed_mesh(), written)
    back = container_shape(written)
    got = np.array(shading_normals(back)).reshape(-1, 3)
    params = mi.traverse(shape)
    corners = np.array(params['vertex_positions']).reshape(-1, 3)[np.array(params['faces']).reshape(-1)]
    n = mi.Vector3f(*(mi.Float(a) for a in np.array(shading_normals(shape)).reshape(-1, 3).T))
    expected = np.array(surroundings.pose.normal_to_world(n)).T
    x = mi.Point3f(*(mi.Float(a) for a in corners.T.astype(np.float32)))
    assert np.abs(np.array(mi.traverse(back)['vertex_positions']).reshape(-1, 3)
                  - np.array(surroundings.pose.to_world(x)).T).max() < 1e-5
    assert np.abs(got - expected).max() < 1e-4
