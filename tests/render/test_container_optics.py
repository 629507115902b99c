"""The container's optics follow its geometry, however its file was written.

A box written with 8 shared vertices and no normals (trimesh, Blender's cube, most
CAD exports) gets smooth vertex normals from Mitsuba; bending light by those, a
box refracts like a rounded lens. The ``reneus`` integrator bends light by the
corner normals of :func:`reneus_mi.geometry.container.corner_normals` instead: flat
across creases, the file's normals (or the faces' mean) where the surface is smooth.
Every way of writing the reference glass block must render like Mitsuba's ``path``
on its ``cube`` shape (flat faces by construction).
"""
import os

import numpy as np
import pytest
import trimesh

import drjit as dr
import mitsuba as mi
from reference import BLOCK_HALF, BLOCK_ROTATION, path_reference, path_scene, reneus_pixels, reneus_scene
from reneus_mi.geometry.container import container_shape, corner_normals, shading_mesh
from reneus_mi.geometry.shapes import container_mesh

RES = 24
#: The tolerances of the integrator's comparison with ``path`` (test_integrator.py).
MEAN_TOL, P99_TOL = 0.003, 0.02
#: Box files exported by Blender 5.0.1 (bpy): its cube scaled to the block, unrotated; the PLYs
#: hold quads (Blender's default), which Mitsuba's own PLY reader refuses.
BLENDER = os.path.join(os.path.dirname(__file__), '..', 'fixtures', 'containers')
ROTATION = np.array(BLOCK_ROTATION.matrix)[:3, :3]


def _box() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=2.0 * np.asarray(BLOCK_HALF))


def _write(folder, name: str, mesh: trimesh.Trimesh, **kwargs) -> str:
    path = os.path.join(folder, name)
    if name.endswith('.ply'):
        data = trimesh.exchange.ply.export_ply(mesh, **kwargs)
    elif name.endswith('.obj'):
        data = trimesh.exchange.obj.export_obj(mesh, **kwargs).encode()
    else:
        data = trimesh.exchange.export.export_mesh(mesh, None, **{'file_type': name.rsplit('.', 1)[1], **kwargs})
        data = data.encode() if isinstance(data, str) else data
    with open(path, 'wb') as f:
        f.write(data)
    return path


def _unshared() -> trimesh.Trimesh:
    mesh = _box()
    mesh.unmerge_vertices()
    return mesh


#: name -> writer(folder) of the same block.
BOXES = {
    'shared8.ply': lambda d: _write(d, 'shared8.ply', _box()),
    'shared8_normals.ply': lambda d: _write(d, 'shared8_normals.ply', _box(), vertex_normal=True),
    'shared8.obj': lambda d: _write(d, 'shared8.obj', _box(), include_normals=False),
    'shared8_normals.obj': lambda d: _write(d, 'shared8_normals.obj', _box(), include_normals=True),
    'unshared36.ply': lambda d: _write(d, 'unshared36.ply', _unshared()),
    'unshared36_face_normals.ply': lambda d: _write(d, 'unshared36_face_normals.ply', _unshared(),
                                                    vertex_normal=True),
    # CAD exports: STL stores one normal per face and a vertex per corner; OFF shares them.
    'shared8.stl': lambda d: _write(d, 'shared8.stl', _box()),
    'shared8_ascii.stl': lambda d: _write(d, 'shared8_ascii.stl', _box(), file_type='stl_ascii'),
    'shared8.off': lambda d: _write(d, 'shared8.off', _box()),
    'blender_cube.ply': lambda d: os.path.join(BLENDER, 'blender_cube.ply'),
    'blender_cube_normals.ply': lambda d: os.path.join(BLENDER, 'blender_cube_normals.ply'),
    'blender_cube_binary.ply': lambda d: os.path.join(BLENDER, 'blender_cube_binary.ply'),
    'blender_cube.obj': lambda d: os.path.join(BLENDER, 'blender_cube.obj'),
    'blender_quads.obj': lambda d: os.path.join(BLENDER, 'blender_cube_quads_nonormals.obj'),
}


@pytest.fixture(scope='module')
def flat_reference():
    """``path`` on the ``cube`` shape, D_re = 2 (path's max_depth 3)."""
    mean, _ = path_reference(path_scene(RES, max_depth=3), 8192)
    return mean


def _placed(shape, R: np.ndarray):
    """``shape`` rotated by ``R`` (its positions and the normals it was read with)."""
    import mitsuba as mi
    params = mi.traverse(shape)
    for key in ('vertex_positions', 'vertex_normals'):
        if key in params and dr.width(params[key]):
            v = np.array(params[key]).reshape(-1, 3)
            params[key] = mi.Float((v @ R.T).astype(np.float32).ravel())
    params.update()
    return shape


def _errors(path, mean, **integrator):
    # The container as the package reads any file (container_shape), placed like the cube.
    import mitsuba as mi
    from reference import AMBIENT, SPHERE_COLOR, SPHERE_RADIUS, sensor
    shape = _placed(container_shape(path, {'type': 'dielectric', 'int_ior': 1.45}), ROTATION)
    scene = mi.load_dict({'type': 'scene', 'sensor': sensor(RES), 'container': shape,
                          'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': AMBIENT}},
                          'integrator': {'type': 'reneus', 'gamma': 1.0, 'max_depth': 2, 'terminal': 'black',
                                         'field': 'sphere', 'field_radius': SPHERE_RADIUS,
                                         'field_color': SPHERE_COLOR, 'field_inv_s': 4000.0, **integrator}})
    d = np.abs(reneus_pixels(scene) - mean)
    return d.mean(), np.percentile(d, 99)


@pytest.mark.parametrize('name', list(BOXES))
def test_every_box_file_refracts_as_a_box(name, flat_reference, tmp_path):
    mean_err, p99 = _errors(BOXES[name](str(tmp_path)), flat_reference)
    assert mean_err < MEAN_TOL and p99 < P99_TOL, (name, mean_err, p99)


def test_smoothing_every_edge_fails_the_comparison(flat_reference, tmp_path):
    # A crease angle of 180 degrees smooths across the box's edges as Mitsuba's recomputed
    # normals do (the behaviour before this rule): the lens is seen.
    mean_err, _ = _errors(BOXES['shared8.ply'](str(tmp_path)), flat_reference, crease_angle=180.0)
    assert mean_err > 2 * MEAN_TOL, mean_err


def test_shading_mesh_renders_the_rule_with_path(flat_reference, tmp_path):
    # The same rule for Mitsuba's own integrators: path through the 8-vertex box made a
    # shading mesh sees a box.
    import mitsuba as mi
    from reference import AMBIENT, SPHERE_COLOR, SPHERE_RADIUS, sensor
    shape = _placed(shading_mesh(BOXES['shared8.ply'](str(tmp_path)),
                                 bsdf={'type': 'dielectric', 'int_ior': 1.45}), ROTATION)
    eta = 1.45 / 1.000277
    sphere = {'type': 'sphere', 'radius': SPHERE_RADIUS,
              'bsdf': {'type': 'diffuse', 'reflectance': {'type': 'rgb', 'value': 0.0}},
              'emitter': {'type': 'area', 'radiance': {'type': 'rgb', 'value': [c * eta * eta for c in SPHERE_COLOR]}}}
    scene = mi.load_dict({'type': 'scene', 'integrator': {'type': 'path', 'max_depth': 3},
                          'sensor': sensor(RES), 'container': shape, 'sphere': sphere,
                          'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': AMBIENT}}})
    mean, _ = path_reference(scene, 4096)
    assert np.abs(mean - flat_reference).mean() < MEAN_TOL


# ------------------------------------------------------------ the rule itself
def _face_normals(mesh):
    return np.repeat(np.asarray(mesh.face_normals)[:, None, :], 3, axis=1)


@pytest.mark.parametrize('normals', [False, True], ids=['no_normals', 'averaged_normals'])
def test_box_corners_take_their_face_normal(normals):
    box = _box()
    n = corner_normals(box.vertices, box.faces, np.asarray(box.vertex_normals) if normals else None)
    assert np.abs(n - _face_normals(box)).max() < 1e-6


def test_smooth_surface_keeps_stored_normals_and_smooths_without():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    exact = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    # A slightly perturbed stored normal is the file's, kept exactly.
    stored = exact + 0.01 * np.random.default_rng(0).normal(size=exact.shape)
    stored /= np.linalg.norm(stored, axis=1, keepdims=True)
    assert np.abs(corner_normals(sphere.vertices, sphere.faces, stored) - stored[sphere.faces]).max() < 1e-6
    # Without stored normals, and written one vertex per corner with per-face normals, the
    # faces' mean: within a facet's angle of the exact normal, not the facets' own normals.
    smooth = corner_normals(sphere.vertices, sphere.faces)
    soup = sphere.copy()
    soup.unmerge_vertices()
    per_face = np.repeat(np.asarray(soup.face_normals), 3, axis=0)
    assert np.abs(corner_normals(soup.vertices, soup.faces, per_face) - smooth).max() < 1e-6
    assert np.degrees(np.arccos(np.clip((smooth * exact[sphere.faces]).sum(-1), -1, 1))).max() < 1.0
    assert np.degrees(np.arccos(np.clip((_face_normals(sphere) * exact[sphere.faces]).sum(-1), -1, 1))).max() > 4.0


@pytest.mark.parametrize('sections', [32, 12])
def test_cylinder_is_smooth_around_and_sharp_at_its_rims(sections):
    # 12 sections meet at exactly the crease angle: smooth at every vertex, not at some.
    cylinder = trimesh.creation.cylinder(radius=0.5, height=1.0, sections=sections)
    n = corner_normals(cylinder.vertices, cylinder.faces)
    side = np.abs(np.asarray(cylinder.face_normals)[:, 2]) < 0.5
    exact = cylinder.vertices[cylinder.faces[side]] * [1, 1, 0]
    exact /= np.linalg.norm(exact, axis=2, keepdims=True)
    assert np.abs(n[side] - exact).max() < 1e-5
    assert np.abs(n[~side] - _face_normals(cylinder)[~side]).max() < 1e-6


@pytest.mark.parametrize('shape', ['box', 'cylinder', 'sphere', 'rounded'])
def test_rays_near_an_edge_are_flagged(shape, tmp_path):
    # model.render.edge_margin: a ray straight through the container is flagged where it enters
    # or leaves within the margin of an edge, and only there: a box's twelve edges (written one
    # vertex per corner, as a soup), a jar's two rims and not its smooth side, a block's edges
    # rounded at 1.5 margins (the rounding itself and the margin beyond it), not a
    # sphere (the surface turns by 6 degrees within the margin: no edge).
    margin = 0.1
    mesh = {'box': lambda: trimesh.creation.box(extents=(2.0, 2.0, 2.0)),
            'cylinder': lambda: trimesh.creation.cylinder(radius=1.0, height=2.0, sections=64),
            'sphere': lambda: trimesh.creation.icosphere(subdivisions=4, radius=1.0),
            # Outer half-size 1, its edges rounded at 0.15 (flat for |y|, |z| <= 0.85): a ray at
            # z = 0.985 meets the rounding 0.16 from its border, flagged for being on it.
            'rounded': lambda: container_mesh('rounded', [1.0 - 0.15 * (1.0 - 1.0 / np.sqrt(3.0))] * 3,
                                              edge=0.15)}[shape]()
    mesh.unmerge_vertices()
    path = _write(str(tmp_path), f'{shape}.ply', mesh)
    scene = reneus_scene(8, mesh=path, field_radius=0.05, edge_margin=margin)
    # Rays along -x at heights z and depths y: through a box's faces x = +-1, through the
    # cylinder's side (a smooth surface) and out.
    z, y = (g.ravel() for g in np.meshgrid(np.linspace(-0.985, 0.985, 40), [-0.95, -0.5, 0.0, 0.5, 0.95]))
    ray = mi.Ray3f(mi.Point3f(5.0, mi.Float(y), mi.Float(z)), mi.Vector3f(-1.0, 0.0, 0.0))
    near = np.array(scene.integrator().render_rays(scene, ray).near_edge)
    border = 0.85 if shape == 'rounded' else 1.0
    # The rounded block's cross-section is a square rounded at 0.15: rays past its corners miss.
    hits = np.hypot(np.maximum(np.abs(y) - border, 0.0), np.maximum(np.abs(z) - border, 0.0)) < 1.0 - border + 1e-6
    expected = hits & (((border - np.abs(z) < margin) & (shape != 'sphere'))
                       | ((shape in ('box', 'rounded')) & (border - np.abs(y) < margin)))
    assert np.array_equal(near, expected) and near.any() == (shape != 'sphere')
