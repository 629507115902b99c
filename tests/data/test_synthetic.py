"""Synthetic data: procedural objects, box fitting, rendered images, masks, cameras, files."""
from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh
from scipy.ndimage import binary_dilation

import mitsuba as mi

import reneus_mi  # noqa: F401  (sets the variant)
from reneus_mi.data import load_dataset, objects, synthetic
from reneus_mi.data.masks import container_masks
from reneus_mi.data.images import as_float
from reneus_mi.synth import main as synth_main

BACKGROUND = synthetic.AMBIENT ** (1.0 / synthetic.GAMMA)


@pytest.mark.parametrize('name', sorted(objects.OBJECTS))
def test_object_closed_normalized_and_boxed(name):
    mesh = objects.load_object(name)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0.0  # outward normals: diffuse shading is one-sided
    obj, box, inside = objects.normalize(mesh, margin=0.15, radius=0.95)
    assert inside is None
    assert np.linalg.norm(obj.vertices, axis=1).max() < 0.95
    np.testing.assert_allclose(np.linalg.norm(box.vertices, axis=1), 0.95, rtol=1e-9)
    assert box.is_watertight and box.volume > 0.0
    # The box is the centred bounding box grown by 15% of the largest half-extent.
    half = 0.5 * obj.extents
    np.testing.assert_allclose(obj.bounds.sum(axis=0), 0.0, atol=1e-9)
    np.testing.assert_allclose(0.5 * box.extents - half, 0.15 * half.max(), rtol=1e-9)
    colors = mesh.visual.vertex_colors[:, :3].astype(float)
    if name == 'statuette':
        assert np.ptp(colors, axis=0).max() == 0  # texture-less by design
    else:
        assert colors.std(axis=0).max() > 20.0  # a visible pattern


def test_insect_has_thin_legs_and_antennae():
    obj, _, _ = objects.normalize(objects.load_object('insect'))
    # Just above the lowest point only the six feet are cut; at z = 0.2 only
    # the two antennae. Every cut is a thin tube (scene diameter is 1.9).
    for z, count in ((obj.bounds[0, 2] + 0.05, 6), (0.2, 2)):
        loops = obj.section(plane_origin=[0.0, 0.0, z], plane_normal=[0.0, 0.0, 1.0]).discrete
        assert len(loops) == count
        widths = np.array([np.ptp(loop[:, :2], axis=0).max() for loop in loops])
        assert np.all(widths < 0.04), widths


def test_mesh_file_is_loaded_colored_and_scaled(tmp_path):
    path = str(tmp_path / 'blob.obj')
    trimesh.creation.icosphere(subdivisions=3, radius=7.0).apply_translation([3, 0, 0]).export(path)
    mesh = objects.load_object(path)
    assert mesh.visual.kind == 'vertex' and mesh.visual.vertex_colors[:, :3].std() > 20.0
    obj, _, _ = objects.normalize(mesh)
    np.testing.assert_allclose(obj.bounds.sum(axis=0), 0.0, atol=1e-9)
    assert np.linalg.norm(obj.vertices, axis=1).max() < 0.95


def test_bad_object_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(ValueError, match="'nope': neither an object name"):
        objects.load_object('nope')
    with pytest.raises(SystemExit) as exit_info:
        synth_main(['nope', '-o', str(tmp_path)])
    assert str(exit_info.value.code).startswith('error: ') and 'nope' in str(exit_info.value.code)
    with pytest.raises(ValueError, match='subsets'):
        synthetic.make_dataset('sphere', str(tmp_path), subsets=('glass',))


def test_cameras_on_sphere_frame_the_unit_sphere():
    K, c2w = synthetic.sample_cameras(200, 64, seed=3)
    np.testing.assert_allclose(np.linalg.norm(c2w[:, :3, 3], axis=1), 5.0)
    # Looking at the origin, a proper rotation, and the unit sphere's outline
    # exactly touches the image border.
    np.testing.assert_allclose(np.einsum('nij,ni->nj', c2w[:, :3, :3], -c2w[:, :3, 3] / 5.0),
                               np.tile([0.0, 0.0, 1.0], (200, 1)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(c2w[:, :3, :3]), 1.0)
    np.testing.assert_allclose(32.0 / K[:, 0, 0], np.tan(np.arcsin(0.2)))
    # Uniform on the sphere: the mean direction is near zero.
    assert np.linalg.norm(c2w[:, :3, 3].mean(axis=0)) / 5.0 < 0.15
    np.testing.assert_array_equal(synthetic.sample_cameras(200, 64, seed=3)[1], c2w)


@pytest.fixture(scope='module')
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp('statuette')
    # The statuette has one arm raised: a mirrored or flipped camera shows.
    return synthetic.make_dataset('statuette', str(out), views=4, res=40, spp=32, seed=1, write=False)


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


def test_images_match_the_recorded_cameras(rendered):
    # The object as the recorded K/c2w see it (pixel-centre rays at gt.ply)
    # against where Mitsuba drew it.
    K, c2w = rendered['K'], rendered['c2w']
    expected = container_masks(rendered['gt_mesh'], K, c2w, 40, 40)
    # Half the object/background contrast: pixels at least half covered.
    drawn = np.abs(rendered['images']['nobox'] - BACKGROUND).max(axis=-1) > 0.1
    assert min(_iou(d, e) for d, e in zip(drawn, expected)) > 0.9
    # The test can tell: a mirrored (x) or upside-down (y) camera would fail it.
    assert _iou(drawn, expected[:, :, ::-1]) < 0.8
    assert _iou(drawn, expected[:, ::-1]) < 0.8
    # Background: the environment, gamma-encoded.
    corner = rendered['images']['box'][:, 0, 0]
    np.testing.assert_allclose(corner, BACKGROUND, atol=1e-6)


def test_masks_are_the_glass_silhouette(rendered):
    box, nobox, masks = rendered['images']['box'], rendered['images']['nobox'], rendered['masks']
    # The box filter lets a pixel whose centre misses the box still see it
    # at its border: one pixel of slack, diagonals included (box corners).
    near = np.stack([binary_dilation(m, np.ones((3, 3), bool)) for m in masks])
    assert 0.2 < masks.mean() < 0.6
    assert np.abs(box - nobox)[~near].max() < 1e-6
    inside = np.abs(box - nobox).mean(axis=-1)[masks]
    # Refraction moves the object: much of the box looks different, far
    # beyond the noise of one render (measured: 0.015 at 32 spp).
    noise = rendered['noise']
    assert 0.005 < noise < 0.025
    assert inside.mean() > 4.0 * noise
    assert np.mean(inside > 5.0 * noise) > 0.3


def test_dataset_round_trip(tmp_path):
    res = synthetic.make_dataset('sphere', str(tmp_path), views=3, res=16, spp=4, seed=2)
    assert sorted(os.listdir(tmp_path)) == ['box', 'box.ply', 'box_neus', 'gt.ply', 'nobox',
                                            'nobox_neus', 'synth.json']
    for subset, with_box in (('box', True), ('nobox', False)):
        assert os.path.isfile(os.path.join(res['paths'][subset]['blender'], 'scene.xml'))
        for fmt, folder in res['paths'][subset].items():
            ds = load_dataset(folder, need_container=with_box)
            np.testing.assert_allclose(ds.K, res['K'], atol=1e-6)
            np.testing.assert_allclose(ds.c2w, res['c2w'], atol=1e-6)
            np.testing.assert_array_equal(ds.masks, res['masks'])
            # 8-bit files: half a step of quantisation.
            np.testing.assert_allclose(as_float(ds.images), res["images"][subset], atol=0.5 / 255 + 1e-6)
            assert ds.ior == (synthetic.IOR if with_box else None)
            assert (ds.container is not None) == with_box
            gt = trimesh.load(ds.gt_mesh)
            np.testing.assert_allclose(gt.bounds, trimesh.load(res['gt_mesh']).bounds, atol=1e-6)


@pytest.mark.parametrize('kind', ['case', 'jar', 'amber'])
def test_containers_of_collections(tmp_path, kind):
    # The generator's case, jar and amber block become datasets whose scene the integrator
    # reads as the same interfaces: the glass, then the air or the liquid inside it.
    synth_main(['insect', '-o', str(tmp_path / kind), '--views', '4', '--res', '24', '--spp', '8',
                '--subsets', 'box', '--container', kind, '--absorption', '0.1', '0.2', '0.3'])
    ds = load_dataset(str(tmp_path / kind / 'box'))
    scene = mi.load_file(str(tmp_path / kind / 'box' / 'scene.xml'))
    found = scene.integrator().bind(scene).interfaces
    outer = trimesh.load(ds.container)
    if kind == 'amber':
        assert not ds.inner and found.count == 1 and np.allclose(ds.absorption, [0.1, 0.2, 0.3])
        assert found.sigma_a == (pytest.approx((0.1, 0.2, 0.3)),)
        return
    inner = trimesh.load(ds.inner[0].mesh)
    wall = (outer.extents - inner.extents) / 2
    ior = {'case': 1.0, 'jar': synthetic.LIQUID_IOR}[kind]
    assert ds.ior == 1.45 and ds.inner[0].ior == ior and ds.absorption is None
    assert np.allclose(ds.inner[0].absorption, [0.1, 0.2, 0.3])
    assert found.count == 2 and found.ior == pytest.approx((1.45, ior), rel=1e-6)
    assert found.sigma_a[0] is None and found.sigma_a[1] == pytest.approx((0.1, 0.2, 0.3))
    # The wall is even all round: WALL of the insect's largest half-extent, in the scene's scale.
    assert wall.max() - wall.min() < 0.02 * wall.max() and wall.min() > 0
