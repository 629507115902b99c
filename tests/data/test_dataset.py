"""Datasets: Blender and NeuS round trips, camera conventions, masks, bad input."""
import json
import os
import shutil

import mitsuba as mi
import numpy as np
import pytest
import trimesh

from reneus_mi.data import Dataset, load_dataset, write_dataset
from reneus_mi.data.cameras import intrinsics, look_at
from reneus_mi.data.dataset import check_same_dataset, dataset_fingerprint
from reneus_mi.data.images import as_float, read_image, write_image
from reneus_mi.data.masks import container_masks
from reneus_mi.utils.errors import ReneusError

H, W = 12, 16
BOX = (1.0, 0.8, 0.6)


def make_dataset(folder) -> Dataset:
    """Three views of a box container, random pixels and masks, varied intrinsics."""
    box = os.path.join(folder, 'box.ply')
    trimesh.creation.box(extents=BOX).export(box)
    rng = np.random.default_rng(0)
    eyes = [(3.0, 0.5, 1.0), (-1.0, 2.5, -0.5), (0.3, -2.8, 1.5)]
    K = np.stack([intrinsics(14.0 + i, 14.0 + i, 8.0 + 0.25 * i, 6.0 - 0.5 * i) for i in range(3)])
    c2w = np.stack([look_at(e) for e in eyes])
    # The loader checks masks against the container's projection: start from
    # it, with a corner pixel set so that a mask read back differs from a recomputed one.
    masks = container_masks(box, K, c2w, H, W)
    masks[:, 0, 0] = True
    return Dataset(images=rng.random((3, H, W, 3)).astype(np.float32),
                   masks=masks, K=K, c2w=c2w,
                   names=['v0.png', 'v1.png', 'v2.png'], root=str(folder),
                   container=box, ior=1.5, absorption=np.array([0.1, 0.2, 0.4]))


@pytest.fixture(scope='module')
def written(tmp_path_factory):
    """The dataset and its two written copies (folders are copied before mutation)."""
    root = tmp_path_factory.mktemp('data')
    ds = make_dataset(root)
    for fmt in ('blender', 'neus'):
        write_dataset(ds, str(root / fmt), fmt)
    return ds, root


def mutable(written, tmp_path, fmt):
    folder = tmp_path / fmt
    shutil.copytree(written[1] / fmt, folder)
    return folder


@pytest.mark.parametrize('fmt', ['blender', 'neus'])
def test_round_trip(written, fmt):
    ds, root = written
    back = load_dataset(str(root / fmt))
    # NeuS pairs image i with world_mat_i by the number in the file name.
    assert back.names == (ds.names if fmt == 'blender' else ['000.png', '001.png', '002.png'])
    assert np.abs(back.K - ds.K).max() < 1e-5
    assert np.abs(back.c2w - ds.c2w).max() < 1e-5
    # 8-bit PNG: half a quantisation step; held as the file's 8 bits.
    assert back.images.dtype == np.uint8
    assert np.abs(as_float(back.images) - ds.images).max() <= 0.5 / 255 + 1e-6
    assert np.array_equal(back.masks, ds.masks)
    assert back.ior == 1.5 and back.gt_mesh is None
    assert np.array_equal(back.absorption, [0.1, 0.2, 0.4])
    assert os.path.dirname(back.container) == str(root / fmt)
    centre, radius = back.normalization()
    assert np.abs(centre).max() < 1e-6 and abs(radius - np.linalg.norm(BOX) / 2) < 1e-6

    rng = np.random.default_rng(1)
    view = rng.integers(0, 3, 50)
    px = np.stack([rng.integers(0, W, 50), rng.integers(0, H, 50)], axis=1)
    (o0, d0), (o1, d1) = ds.rays(view, px), back.rays(view, px)
    assert np.abs(o1 - o0).max() < 1e-5 and np.abs(d1 - d0).max() < 1e-5
    assert np.allclose(np.linalg.norm(d1, axis=1), 1.0)


def test_rays_follow_K():
    """A ray through pixel (x, y) reprojects to (x + 0.5, y + 0.5)."""
    K = intrinsics(20.0, 18.0, 7.0, 5.5)[None]
    c2w = look_at((1.0, 2.0, 3.0))[None]
    ds = Dataset(np.zeros((1, H, W, 3), np.float32), np.ones((1, H, W), bool), K, c2w, ['a'], '.')
    px = np.array([[0, 0], [15, 11], [3, 9]])
    o, d = ds.rays(0, px)
    p_cam = np.einsum('ij,mj->mi', np.linalg.inv(c2w[0]), np.c_[o + 2.0 * d, np.ones(3)])[:, :3]
    uv = np.einsum('ij,mj->mi', K[0], p_cam)
    assert np.abs(uv[:, :2] / uv[:, 2:] - (px + 0.5)).max() < 1e-9


def test_image_encodings(tmp_path):
    """Linear EXR comes back sRGB-encoded; grey PNG becomes RGB; alpha is kept apart."""
    mi.Bitmap(np.full((2, 3, 3), 0.2, np.float32)).write(str(tmp_path / 'lin.exr'))
    rgb, alpha = read_image(str(tmp_path / 'lin.exr'))
    assert alpha is None and np.allclose(rgb, 1.055 * 0.2 ** (1 / 2.4) - 0.055, atol=1e-5)
    write_image(str(tmp_path / 'grey.png'), np.full((2, 3), 0.4))
    rgb, alpha = read_image(str(tmp_path / 'grey.png'))
    assert alpha is None and rgb.shape == (2, 3, 3) and np.allclose(rgb, 102 / 255)
    write_image(str(tmp_path / 'rgba.png'), np.dstack([np.full((2, 3, 3), 0.6), np.eye(2, 3)]))
    rgb, alpha = read_image(str(tmp_path / 'rgba.png'))
    assert np.allclose(rgb, 153 / 255) and np.array_equal(alpha, np.eye(2, 3))


def test_blender_opengl_convention(tmp_path):
    """A hand-written transforms.json: OpenGL c2w, no extensions, RGB images."""
    h, w = 13, 17  # odd: pixel (8, 6) is centred on the principal point
    eye = np.array([0.0, -4.0, 1.0])
    back = eye / np.linalg.norm(eye)  # OpenGL cameras look down -z
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    gl = np.eye(4)
    gl[:3, 0], gl[:3, 1], gl[:3, 2], gl[:3, 3] = right, np.cross(back, right), back, eye
    trimesh.creation.box(extents=BOX).export(tmp_path / 'glass.obj')
    os.makedirs(tmp_path / 'train')
    write_image(str(tmp_path / 'train' / 'r_0.png'), np.full((h, w, 3), 0.5))
    meta = {'camera_angle_x': 0.6, 'IOR': 1.45, 'mesh_outside': 'glass.obj',
            'frames': [{'file_path': './train/r_0', 'transform_matrix': gl.tolist()}]}
    (tmp_path / 'transforms.json').write_text(json.dumps(meta))

    ds = load_dataset(str(tmp_path))
    assert ds.names == ['r_0.png'] and ds.ior == 1.45
    assert np.isclose(ds.K[0, 0, 0], 0.5 * w / np.tan(0.3)) and ds.K[0, 0, 2] == w / 2
    o, d = ds.rays(0, np.array([[8, 6], [16, 6], [8, 12]]))
    # The centre ray passes through the origin the camera looks at...
    assert np.linalg.norm(np.cross(-o[0], d[0])) < 1e-12 and d[0] @ -o[0] > 0
    # ...image x goes right, image y goes down (OpenGL's up is -y).
    assert (d[1] - d[0]) @ gl[:3, 0] > 0.1 and (d[2] - d[0]) @ gl[:3, 1] < -0.1
    # RGB images: the masks are the container's projection, the box is in the middle.
    assert ds.masks[0, 6, 8] and not ds.masks[0, 0, 0]


def test_masks_match_box_projection(tmp_path):
    """Camera on +z looking down at the box: its silhouette is the front face."""
    trimesh.creation.box(extents=BOX).export(tmp_path / 'box.ply')
    h, w, f, dist = 24, 32, 20.0, 3.0
    K = intrinsics(f, f, 15.0, 12.5)[None]
    c2w = look_at((0.0, 0.0, dist), up=(0.0, 1.0, 0.0))[None]
    mask = container_masks(str(tmp_path / 'box.ply'), K, c2w, h, w)[0]
    # Pixel centre (u, v) meets the front face z = 0.3 at (X, Y); image y is world -y.
    v, u = np.mgrid[:h, :w] + 0.5
    depth = dist - BOX[2] / 2
    x, y = (u - 15.0) / f * depth, -(v - 12.5) / f * depth
    expected = (np.abs(x) < BOX[0] / 2) & (np.abs(y) < BOX[1] / 2)
    assert 0 < expected.sum() < h * w
    assert np.array_equal(mask, expected)


def test_neus_without_masks_projects_container(written, tmp_path):
    ds = written[0]
    folder = mutable(written, tmp_path, 'neus')
    shutil.rmtree(folder / 'mask')
    back = load_dataset(str(folder))
    assert np.array_equal(back.masks, container_masks(ds.container, ds.K, ds.c2w, H, W))
    assert back.masks.any() and not back.masks.all()


def test_without_container(written, tmp_path):
    folder = mutable(written, tmp_path, 'blender')
    meta = json.loads((folder / 'transforms.json').read_text())
    del meta['mesh_outside']
    (folder / 'transforms.json').write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"transforms.json: dataset has no container mesh"):
        load_dataset(str(folder))
    ds = load_dataset(str(folder), need_container=False)
    assert ds.container is None and np.array_equal(ds.masks, written[0].masks)
    with pytest.raises(ValueError, match="neither a NeuS scale_mat nor a container"):
        ds.normalization()


def _edit_json(path, edit):
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))


def test_blender_errors(written, tmp_path):
    folder = mutable(written, tmp_path, 'blender')
    meta_path = folder / 'transforms.json'
    original = meta_path.read_text()

    os.rename(folder / 'images' / 'v1.png', folder / 'v1.png')
    with pytest.raises(ValueError, match=r"frames\[1\]: image 'images/v1.png' is missing"):
        load_dataset(str(folder))
    os.rename(folder / 'v1.png', folder / 'images' / 'v1.png')

    _edit_json(meta_path, lambda m: m['frames'][2].update(
        transform_matrix=[[1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    with pytest.raises(ValueError, match=r"frames\[2\]: transform_matrix: camera matrix is not "
                                         "invertible"):
        load_dataset(str(folder))
    meta_path.write_text(original)

    _edit_json(meta_path, lambda m: m['frames'][0].pop('fl_x'))
    with pytest.raises(ValueError, match="expected intrinsics 'camera_angle_x' or 'fl_x'"):
        load_dataset(str(folder))
    meta_path.write_text('{"frames": [')
    with pytest.raises(ValueError, match="transforms.json: transforms file is not valid JSON"):
        load_dataset(str(folder))
    # Saved by a Windows editor, with a byte-order mark: read as it is.
    meta_path.write_bytes(b'\xef\xbb\xbf' + original.encode())
    assert len(load_dataset(str(folder))) == len(json.loads(original)['frames'])
    meta_path.write_text(original)

    write_image(str(folder / 'images' / 'v2.png'), np.zeros((H + 1, W, 3)))
    with pytest.raises(ValueError, match=r"frames\[2\]: 'h' is 12, but the image is 16x13"):
        load_dataset(str(folder))
    (folder / 'images' / 'v2.png').write_bytes(b'not a png')
    with pytest.raises(ValueError, match=r"v2.png: unreadable image"):
        load_dataset(str(folder))


def test_neus_errors(written, tmp_path):
    folder = mutable(written, tmp_path, 'neus')
    os.rename(folder / 'image' / '002.png', tmp_path / '002.png')
    with pytest.raises(ValueError, match=r"image: has 2 images, but .*cameras_sphere.npz has 3 "
                                         r"cameras; .* missing \[2\]"):
        load_dataset(str(folder))
    write_image(str(folder / 'image' / '002.png'), np.zeros((H, W + 2, 3)))
    with pytest.raises(ValueError, match=r"002.png: image is 18x12, but .*000.png is 16x12"):
        load_dataset(str(folder))
    shutil.copy(tmp_path / '002.png', folder / 'image' / '002.png')
    write_image(str(folder / 'mask' / '001.png'), np.ones((H - 1, W)))
    with pytest.raises(ValueError, match=r"mask of .*001.png: is 16x11, expected the image size "
                                         "16x12"):
        load_dataset(str(folder))
    os.remove(folder / 'mask' / '001.png')
    with pytest.raises(ValueError, match=r"mask: has 2 images, but .* missing \[1\]"):
        load_dataset(str(folder))
    shutil.copy(written[1] / 'neus' / 'mask' / '001.png', folder / 'mask')

    cams = dict(np.load(folder / 'cameras_sphere.npz'))
    cams['world_mat_1'] = np.diag([1.0, 1.0, 0.0, 1.0])
    np.savez(folder / 'cameras_sphere.npz', **cams)
    with pytest.raises(ValueError, match="world_mat_1: camera matrix is not invertible"):
        load_dataset(str(folder))
    cams = dict(np.load(written[1] / 'neus' / 'cameras_sphere.npz'))
    cams['scale_mat_2'] = 2.0 * cams['scale_mat_2']
    np.savez(folder / 'cameras_sphere.npz', **cams)
    with pytest.raises(ValueError, match="scale_mat_2: expected a 4x4 matrix equal to scale_mat_0"):
        load_dataset(str(folder))
    shutil.copy(written[1] / 'neus' / 'cameras_sphere.npz', folder)

    open_box = trimesh.creation.box(extents=BOX)
    open_box.update_faces(np.arange(len(open_box.faces)) != 0)
    open_box.export(folder / 'container.ply')
    with pytest.raises(ValueError, match="container.ply: container mesh is not closed"):
        load_dataset(str(folder))
    (folder / 'reneus.json').write_text(json.dumps({'mesh_outside': 'nowhere.ply'}))
    with pytest.raises(ValueError, match="reneus.json: 'mesh_outside' names .*nowhere.ply, which "
                                         "does not exist"):
        load_dataset(str(folder))


def test_unknown_format(tmp_path):
    with pytest.raises(ValueError, match="unknown dataset format"):
        load_dataset(str(tmp_path))
    with pytest.raises(ValueError, match="dataset folder is missing"):
        load_dataset(str(tmp_path / 'absent'))


def test_write_checks_first(written, tmp_path):
    ds = written[0]
    with pytest.raises(ValueError, match="format 'colmap': expected one of blender, neus"):
        write_dataset(ds, str(tmp_path / 'out'), 'colmap')
    bad_c2w = ds.c2w.copy()
    bad_c2w[1, :3, :3] *= 2.0
    bad = Dataset(**{**vars(ds), 'c2w': bad_c2w})
    with pytest.raises(ValueError, match=r"c2w\[1\]: camera matrix is not a rotation"):
        write_dataset(bad, str(tmp_path / 'out'), 'neus')
    bad = Dataset(**{**vars(ds), 'masks': ds.masks[:, :-1]})
    with pytest.raises(ValueError, match=r"masks: expected shape \(3, 12, 16\)"):
        write_dataset(bad, str(tmp_path / 'out'), 'blender')
    assert not (tmp_path / 'out').exists()

    folder = mutable(written, tmp_path, 'neus')
    before = {p: p.read_bytes() for p in folder.rglob('*') if p.is_file()}
    with pytest.raises(ValueError, match="neus: lies in the dataset folder"):
        write_dataset(ds, str(folder), 'neus')
    (tmp_path / 'other').mkdir()
    (tmp_path / 'other' / 'notes.txt').write_text('mine')
    with pytest.raises(ValueError, match=r"other: is not empty \(holds notes.txt\)"):
        write_dataset(ds, str(tmp_path / 'other'), 'blender')
    assert all(p.read_bytes() == data for p, data in before.items())
    assert os.listdir(tmp_path / 'other') == ['notes.txt']


# ------------------------------------------------- pairing photos with cameras
def ring_dataset(folder, n=12) -> Dataset:
    """``n`` views around the box; image i is the constant grey i / n (its identity)."""
    box = os.path.join(folder, 'box.ply')
    trimesh.creation.box(extents=BOX).export(box)
    angles = 2 * np.pi * np.arange(n) / n
    c2w = np.stack([look_at((3 * np.cos(a), 3 * np.sin(a), 1.0)) for a in angles])
    K = np.tile(intrinsics(14.0, 14.0, 8.0, 6.0), (n, 1, 1))
    images = np.broadcast_to((np.arange(n) / n)[:, None, None, None], (n, H, W, 3))
    return Dataset(images=images.astype(np.float32), masks=container_masks(box, K, c2w, H, W),
                   K=K, c2w=c2w, names=[f'v{i}.png' for i in range(n)], root=str(folder),
                   container=box, ior=1.5)


def test_neus_views_follow_the_number_in_the_name(tmp_path):
    """0.png ... 11.png: view 10 is world_mat_10, not the third file in text order."""
    ds = ring_dataset(tmp_path)
    folder = tmp_path / 'neus'
    write_dataset(ds, str(folder), 'neus')
    for sub in ('image', 'mask'):
        for i in range(12):
            os.rename(folder / sub / f'{i:03d}.png', folder / sub / f'{i}.png')
    back = load_dataset(str(folder))
    assert back.names == [f'{i}.png' for i in range(12)]
    grey = as_float(back.images[:, 0, 0, 0])
    assert np.abs(grey - np.arange(12) / 12).max() <= 0.5 / 255 + 1e-6
    assert np.abs(back.c2w - ds.c2w).max() < 1e-5


@pytest.mark.parametrize('rename, message', [
    (('1.png', '01.png'), r"1.png both name view 1|01.png and 1.png both name view 1"),
    (('3.png', 'three.png'), r"three.png: expected exactly one view number"),
    (('5.png', '12.png'), r"missing \[5\], unexpected \[12\]"),
])
def test_neus_ambiguous_names_are_errors(tmp_path, rename, message):
    ds = ring_dataset(tmp_path)
    folder = tmp_path / 'neus'
    write_dataset(ds, str(folder), 'neus')
    shutil.rmtree(folder / 'mask')
    for i in range(12):
        os.rename(folder / 'image' / f'{i:03d}.png', folder / 'image' / f'{i}.png')
    src, dst = rename
    if src == '1.png':
        shutil.copy(folder / 'image' / src, folder / 'image' / dst)
        os.remove(folder / 'image' / '11.png')  # keep the count equal to the cameras'
    else:
        os.rename(folder / 'image' / src, folder / 'image' / dst)
    with pytest.raises(ValueError, match=message):
        load_dataset(str(folder))


def test_blender_follows_its_frames_list(tmp_path):
    """Frames listed out of name order keep their own camera."""
    ds = ring_dataset(tmp_path)
    folder = tmp_path / 'blender'
    write_dataset(ds, str(folder), 'blender')
    meta = json.loads((folder / 'transforms.json').read_text())
    meta['frames'] = meta['frames'][::-1]
    (folder / 'transforms.json').write_text(json.dumps(meta))
    back = load_dataset(str(folder))
    assert back.names == [f'v{i}.png' for i in reversed(range(12))]
    assert np.abs(as_float(back.images[:, 0, 0, 0]) - np.arange(12)[::-1] / 12).max() <= 0.5 / 255 + 1e-6
    assert np.abs(back.c2w - ds.c2w[::-1]).max() < 1e-5


# ------------------------------------------------------- container and poses
def test_inverted_container_is_refused(written, tmp_path):
    folder = mutable(written, tmp_path, 'blender')
    box = trimesh.load(folder / 'container.ply', process=False)
    box.invert()
    box.export(folder / 'container.ply')
    with pytest.raises(ValueError, match=r"container.ply: container normals point inward "
                                         r"\(signed volume -0.48\)"):
        load_dataset(str(folder))


def _edit_poses(folder, edit):
    meta = json.loads((folder / 'transforms.json').read_text())
    for i, frame in enumerate(meta['frames']):
        frame['transform_matrix'] = edit(i, np.array(frame['transform_matrix'])).tolist()
    (folder / 'transforms.json').write_text(json.dumps(meta))


@pytest.mark.parametrize('edit, message', [
    # OpenCV axes written where OpenGL's are expected: the camera looks away.
    (lambda i, m: m @ np.diag([1.0, -1.0, -1.0, 1.0]), r"v0.png: view 0: the container centre is behind"),
    # World-to-camera given as camera-to-world.
    (lambda i, m: np.linalg.inv(m), r"view 0: the container centre (is behind|projects to)"),
    # One view turned around.
    (lambda i, m: m @ np.diag([-1.0, 1.0, -1.0, 1.0]) if i == 2 else m,
     r"v2.png: view 2: the container centre is behind"),
    # Cameras 100x further away: the container is a speck.
    (lambda i, m: np.vstack([np.hstack([m[:3, :3], 100 * m[:3, 3:]]), m[3]]),
     r"view 0: the container spans about 0.06.* pixels"),
    # A camera inside the container.
    (lambda i, m: np.vstack([np.hstack([m[:3, :3], [[0.1], [0.0], [0.0]]]), m[3]]) if i == 1 else m,
     r"v1.png: view 1: the camera at \[0.1, 0.0, 0.0\] is inside the container"),
    (lambda i, m: m * np.array([[-1, 1, 1, 1]] * 3 + [[1, 1, 1, 1]]),
     r"frames\[0\]: transform_matrix: rotation part has determinant -1, a mirror"),
])
def test_mis_posed_views_are_named(written, tmp_path, edit, message):
    folder = mutable(written, tmp_path, 'blender')
    _edit_poses(folder, edit)
    with pytest.raises(ValueError, match=message):
        load_dataset(str(folder))


def test_mask_disagreeing_with_the_projection(written, tmp_path):
    folder = mutable(written, tmp_path, 'neus')
    write_image(str(folder / 'mask' / '001.png'), np.zeros((H, W)))
    write_image(str(folder / 'mask' / '001.png'), np.pad(np.ones((3, 3)), ((0, H - 3), (0, W - 3))))
    with pytest.raises(ValueError, match=r"001.png: view 1: the mask from \S+mask/001.png overlaps the "
                                         r"container's projection by IoU 0.0"):
        load_dataset(str(folder))


@pytest.mark.parametrize('ior', [1e6, 1.0, 0.5, 'glass'])
def test_ior_out_of_range(written, tmp_path, ior):
    folder = mutable(written, tmp_path, 'blender')
    _edit_json(folder / 'transforms.json', lambda m: m.update(IOR=ior))
    with pytest.raises(ValueError, match=r"transforms.json: 'IOR' is .*; expected a number in \(1, 3\]"):
        load_dataset(str(folder))


@pytest.mark.parametrize('absorption', [-0.1, 'amber', [1.0, 2.0], [0.1, float('nan'), 0.2]])
def test_absorption_must_be_a_coefficient(written, tmp_path, absorption):
    folder = mutable(written, tmp_path, 'blender')
    _edit_json(folder / 'transforms.json', lambda m: m.update(absorption=absorption))
    with pytest.raises(ValueError, match=r"transforms.json: 'absorption' is .*; expected an absorption "
                                         r"coefficient >= 0 per world unit"):
        load_dataset(str(folder))


def _nested(written, tmp_path):
    """The dataset as a glass case: its box, and a smaller box of air inside."""
    folder = mutable(written, tmp_path, 'blender')
    trimesh.creation.box(extents=np.array(BOX) * 0.8).export(folder / 'cavity.ply')
    return folder


def test_nested_containers_read_and_written(written, tmp_path):
    folder = _nested(written, tmp_path)
    _edit_json(folder / 'transforms.json', lambda m: m.update(containers=[
        {'mesh': m['mesh_outside'], 'int_ior': 1.5, 'ext_ior': 1.0},
        {'mesh': 'cavity.ply', 'int_ior': 1.0, 'ext_ior': 1.5, 'absorption': [0.0, 0.1, 0.2]}]))
    ds = load_dataset(str(folder))
    assert ds.ior == 1.5 and len(ds.inner) == 1
    assert ds.inner[0].mesh == str(folder / 'cavity.ply') and ds.inner[0].ior == 1.0
    assert np.array_equal(ds.inner[0].absorption, [0.0, 0.1, 0.2])
    for fmt in ('blender', 'neus'):
        back = load_dataset(write_dataset(ds, str(tmp_path / f'again_{fmt}'), fmt) or str(tmp_path / f'again_{fmt}'))
        assert back.inner[0].ior == 1.0 and np.array_equal(back.inner[0].absorption, [0.0, 0.1, 0.2])
        assert os.path.basename(back.inner[0].mesh) == 'container_inner_1.ply'


@pytest.mark.parametrize('entries, message', [
    (lambda m: [{'mesh': m['mesh_outside'], 'int_ior': 1.5}, {'mesh': 'cavity.ply', 'int_ior': 1.0, 'ext_ior': 1.33}],
     r"'containers'\[1\]: ext_ior 1.33, but the IOR around it is 1.5 \(containers\[0\].int_ior\); expected the same"),
    (lambda m: [{'mesh': m['mesh_outside'], 'int_ior': 1.6}],
     r"'containers'\[0\]: 1.6, but 'IOR' says 1.5; expected the same"),
    (lambda m: [{'mesh': m['mesh_outside'], 'int_ior': 1.5}, {'mesh': 'cavity.ply', 'int_ior': 1.0, 'absorption': -1}],
     r"'containers'\[1\].absorption is -1; expected an absorption coefficient >= 0"),
    (lambda m: [{'mesh': m['mesh_outside'], 'int_ior': 1.5}, {'mesh': 'missing.ply', 'int_ior': 1.0}],
     r"'containers'\[1\].mesh names .*missing.ply, which does not exist"),
    (lambda m: [{'mesh': m['mesh_outside'], 'ior': 1.5}],
     r"'containers'\[0\]: keys \['ior', 'mesh'\]; expected 'mesh', 'int_ior'"),
], ids=['ior_pair', 'outer_ior', 'negative_absorption', 'missing_mesh', 'unknown_key'])
def test_nested_containers_refused_by_name(written, tmp_path, entries, message):
    folder = _nested(written, tmp_path)
    _edit_json(folder / 'transforms.json', lambda m: m.update(containers=entries(m)))
    with pytest.raises(ValueError, match='transforms.json: ' + message):
        load_dataset(str(folder))


def test_matrix_messages_name_the_defect():
    from reneus_mi.data.cameras import check_c2w, decompose_projection
    m = np.eye(4)
    m[:3, :3] *= [-4.0, 1.0, 1.0]
    with pytest.raises(ValueError, match=r"where: rotation part has determinant -4, a mirror"):
        check_c2w(m, 'where')
    m = np.eye(4)
    m[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"world_mat_3: entry \[2\]\[1\] is nan; expected finite"):
        decompose_projection(m, 'world_mat_3')
    with pytest.raises(ValueError, match=r"c2w: entry \[2\]\[1\] is nan"):
        check_c2w(m, 'c2w')


def test_dataset_fingerprint():
    class DS:
        root, width, height, names = '/d', 4, 3, ['a.png', 'b.png']
        c2w = np.stack([np.eye(4)] * 2)

        def __len__(self):
            return 2
    saved = dataset_fingerprint(DS())
    check_same_dataset(saved, DS(), 'config.json')
    other = DS()
    other.names = ['a.png', 'c.png']
    with pytest.raises(ReneusError, match=r"differs from the run's \(names"):
        check_same_dataset(saved, other, 'config.json')
    moved = DS()
    moved.c2w = moved.c2w.copy()
    moved.c2w[1, 0, 3] = 0.5
    with pytest.raises(ReneusError, match='other camera positions'):
        check_same_dataset(saved, moved, 'config.json')


@pytest.mark.parametrize('fmt', ['blender', 'neus'])
def test_max_size_reduces_photographs_and_cameras_alike(written, fmt):
    """A photograph reduced by area averaging keeps its rays: the reduced pixel (x, y) is the
    original 2x2 block, whose centre is the original point (2x + 1, 2y + 1)."""
    _, root = written
    full, half = load_dataset(str(root / fmt)), load_dataset(str(root / fmt), max_size=W // 2)
    assert half.images.shape == (3, H // 2, W // 2, 3)
    blocks = as_float(full.images).reshape(3, H // 2, 2, W // 2, 2, 3).mean(axis=(2, 4))
    # Held in the files' 8 bits: the average to half a step.
    assert np.abs(as_float(half.images) - blocks).max() <= 0.5 / 255 + 1e-6
    assert np.array_equal(half.masks, full.masks.reshape(3, H // 2, 2, W // 2, 2).mean(axis=(2, 4)) >= 0.5)
    assert np.allclose(half.K, np.diag([0.5, 0.5, 1.0]) @ full.K)
    px = np.tile(np.stack(np.meshgrid(np.arange(W // 2), np.arange(H // 2)), -1).reshape(-1, 2), (3, 1))
    view = np.repeat(np.arange(3), len(px) // 3)
    (o0, d0), (o1, d1) = full.rays(view, 2 * px + 0.5), half.rays(view, px)
    assert np.abs(o1 - o0).max() < 1e-9 and np.abs(d1 - d0).max() < 1e-9
    assert dataset_fingerprint(half)['width'] == W // 2


def test_container_written_with_y_up_is_named(written, tmp_path):
    # Blender's OBJ and PLY exporters write y up by default, while its cameras (and so
    # transforms.json) keep z up: the masks then disagree, and the message says why.
    from reneus_mi.data.checks import Y_UP_TO_Z_UP
    folder = mutable(written, tmp_path, 'blender')
    box = trimesh.load(folder / 'container.ply', process=False)
    box.vertices = box.vertices @ Y_UP_TO_Z_UP       # world -> the file's y-up coordinates
    box.export(folder / 'container.ply')
    with pytest.raises(ValueError, match=r"container.ply: the masks overlap the container's projection by "
                                         r"mean IoU 0.\d\d, and by 0.9\d with the mesh turned from y up to z up: "
                                         r"its file was written with y up"):
        load_dataset(str(folder))
