"""A solid block's faces bulging (``model.render.bow``, :mod:`reneus_mi.render.bow`): the bowed
block renders as Mitsuba's path tracer sees a finely cut mesh of it, each face's bulge moves
that face alone, no bulge is the flat block, and what is not one solid block is refused."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
import trimesh

from reference import (BLOCK_HALF, BLOCK_ROTATION, path_reference, path_scene, pixel_rays, reneus_pixels,
                       reneus_scene)
from reneus_mi.render.interfaces import display_case
from reneus_mi.utils.errors import ReneusError

RES = 24
SPP = 4096
#: Every face's bulge at its centre: 6 % of the block's smallest half-size, a strong lens.
BOW = 0.03
#: Mean absolute difference per pixel and channel allowed against the path tracer (its noise
#: at 4,096 samples, and a facet's chord against the exact bulge): measured 0.00085; the flat
#: block 0.0115.
MEAN_TOL = 0.002


def bowed_box(bow: float, cuts: int = 48) -> trimesh.Trimesh:
    """The reference: each face of the block of half-sizes BLOCK_HALF a grid of ``cuts`` x ``cuts``
    cells, its points moved out by ``bow (1 - u^2)(1 - v^2)``, with the surface's exact normals
    (faces apart, so that each edge keeps both faces' normals)."""
    h = np.asarray(BLOCK_HALF, np.float64)
    vertices, normals, faces = [], [], []
    t = np.linspace(-1.0, 1.0, cuts + 1)
    u, v = (g.ravel() for g in np.meshgrid(t, t, indexing='ij'))
    i, j = np.meshgrid(np.arange(cuts), np.arange(cuts), indexing='ij')
    v00 = (i * (cuts + 1) + j).ravel()
    cells = np.concatenate([np.stack([v00, v00 + cuts + 1, v00 + cuts + 2], 1), np.stack([v00, v00 + cuts + 2, v00 + 1], 1)])
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        for s in (-1.0, 1.0):
            p = np.zeros((len(u), 3))
            p[:, b], p[:, c] = u * h[b], v * h[c]
            p[:, a] = s * (h[a] + bow * (1 - u * u) * (1 - v * v))
            # The face is s x_a = h_a + H(x_b, x_c): its outward normal s e_a - grad H.
            n = np.zeros_like(p)
            n[:, a] = s
            n[:, b] = bow * 2 * u / h[b] * (1 - v * v)
            n[:, c] = bow * 2 * v / h[c] * (1 - u * u)
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            f = cells if s > 0 else cells[:, ::-1]
            faces.append(f + len(vertices) * len(u))
            vertices.append(p)
            normals.append(n)
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), vertex_normals=np.concatenate(normals),
                           process=False)


def _placed(mesh: trimesh.Trimesh, path) -> str:
    """``mesh`` where the reference block stands (BLOCK_ROTATION), normals turned with it."""
    R = np.array(BLOCK_ROTATION.matrix)[:3, :3]
    normals = mesh.vertex_normals @ R.T if 'vertex_normals' in mesh._cache else None
    placed = trimesh.Trimesh(mesh.vertices @ R.T, mesh.faces, vertex_normals=normals, process=False)
    placed.export(str(path))
    return str(path)


def _flat_block(tmp_path) -> str:
    return _placed(trimesh.creation.box(extents=2 * np.asarray(BLOCK_HALF)), tmp_path / 'flat.ply')


def _bowed_scene(tmp_path, bow=BOW):
    """``reneus`` on the flat block's file modelled bowed, every face by ``bow``."""
    scene = reneus_scene(RES, mesh=_flat_block(tmp_path), bow=True, max_depth=2, terminal='black')
    mi.set_property(scene.integrator().bind(scene).bow.bow, mi.Float([bow] * 6))
    return scene


@pytest.fixture(scope='module')
def bowed_reference(tmp_path_factory):
    """``path`` on the finely cut bowed block, D_re = 2 (path's max_depth 3)."""
    path = _placed(bowed_box(BOW), tmp_path_factory.mktemp('bow') / 'bowed.ply')
    mean, _ = path_reference(path_scene(RES, max_depth=3, mesh=path), SPP)
    return mean


def test_a_bowed_block_renders_as_the_path_tracer_sees_it(bowed_reference, tmp_path):
    bowed = np.abs(reneus_pixels(_bowed_scene(tmp_path)) - bowed_reference).mean()
    flat = np.abs(reneus_pixels(_bowed_scene(tmp_path, bow=0.0)) - bowed_reference).mean()
    assert bowed < MEAN_TOL, bowed
    # The bulge is seen: the flat block misses the photograph by several times as much.
    assert flat > 3 * bowed, (flat, bowed)


def test_no_bulge_is_the_flat_block(tmp_path):
    # The same surface cut 64 times finer: float rounding of the hits and their normals.
    flat = reneus_pixels(reneus_scene(RES, mesh=_flat_block(tmp_path), max_depth=2, terminal='black'))
    assert np.abs(reneus_pixels(_bowed_scene(tmp_path, bow=0.0)) - flat).max() < 1e-4


@pytest.mark.parametrize('face', range(6))
def test_a_faces_bulge_moves_that_face_alone(face, tmp_path):
    scene = reneus_scene(RES, mesh=_flat_block(tmp_path), bow=True)
    surroundings = scene.integrator().bind(scene)
    bow = surroundings.bow
    flat = np.array(mi.traverse(bow.shape)['vertex_positions']).reshape(-1, 3)
    mi.set_property(bow.bow, mi.Float(np.eye(6)[face] * BOW))
    bow.sync(surroundings.container)
    moved = np.array(mi.traverse(bow.shape)['vertex_positions']).reshape(-1, 3) - flat
    # The face's outward axis (the block's frame is its bounding box's: faces -x +x -y +y -z +z).
    axis = (2 * (face % 2) - 1) * bow.to_local[face // 2, :3]
    on_face = np.abs(flat @ axis - (flat @ axis).max()) < 1e-5
    assert np.abs(moved[~on_face]).max() < 1e-6
    assert (moved[on_face] @ axis).max() == pytest.approx(BOW, rel=1e-3)
    assert np.abs(moved[on_face] - np.outer(moved[on_face] @ axis, axis)).max() < 1e-6


@pytest.mark.parametrize('shapes, expected', [
    (lambda path: {'ball': {'type': 'sphere', 'bsdf': {'type': 'dielectric'}}},
     r"^model.render.bow: the container 'ball' is a Sphere; expected a block as a triangle mesh"),
    (lambda path: {'jar': {'type': 'ply', 'filename': path, 'bsdf': {'type': 'dielectric'}}},
     r"^model.render.bow: the container 'jar' fills 7\d % of its bounding box; expected a block"),
    (lambda path: display_case(BLOCK_HALF, 0.06, 1.5, BLOCK_ROTATION),
     r'^model.render.bow: the container is not one solid block'),
])
def test_what_is_not_one_solid_block_is_refused(shapes, expected, tmp_path):
    path = str(tmp_path / 'jar.ply')
    trimesh.creation.cylinder(radius=0.5, height=1.0, sections=48).export(path)
    scene = reneus_scene(RES, shapes=shapes(path), bow=True)
    with pytest.raises(ReneusError, match=expected):
        scene.integrator().bind(scene)


def test_the_edges_flagged_are_the_blocks_as_loaded(tmp_path):
    """A rounded block's rays near its edges (``edge_margin``) are flagged alike with the bulge
    modelled: its finer cut is not taken for more rounding (each piece of a rounding's facet,
    narrower, would turn faster), nor its edges for more segments."""
    from reneus_mi.capture.placement import local_mesh
    mesh = local_mesh('box', 2 * np.asarray(BLOCK_HALF), edge=0.15)
    path = _placed(trimesh.Trimesh(mesh.vertices - mesh.bounds.mean(axis=0), mesh.faces), tmp_path / 'rounded.ply')
    flags, segments = [], []
    for bow in (False, True):
        scene = reneus_scene(RES, mesh=path, edge_margin=0.2, bow=bow)
        flags.append(np.array(scene.integrator().render_rays(scene, pixel_rays(scene)).near_edge))
        segments.append(dr.width(scene.integrator().bind(scene).edge_segments[0].x))
    assert segments[1] == segments[0]
    assert flags[0].mean() > 0.05 and np.mean(flags[0] != flags[1]) < 0.01, (flags[0].mean(), np.mean(flags[0] != flags[1]))
