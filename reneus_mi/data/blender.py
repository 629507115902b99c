"""NeRF/Blender ``transforms.json`` datasets (also nerfstudio's variant).

Layout read::

    DATA_DIR/transforms.json       (or transforms_train.json)
    DATA_DIR/<file_path>[.png]     one image per frame, RGB or RGBA

Intrinsics are ``camera_angle_x`` (optionally ``camera_angle_y``; principal
point at the image centre) or ``fl_x``/``fl_y``/``cx``/``cy`` (optionally
``w``/``h``), at the top level or per frame (a frame's own value wins). Each
frame has ``file_path`` (with or without extension, relative to the folder) and
``transform_matrix``: camera-to-world with OpenGL axes. nerfstudio's lens distortion
(``camera_model: OPENCV`` with ``k1``, ``k2``, ``p1``, ``p2`` and optionally ``k3``, at the
top level or per frame) is taken out on reading: each image is resampled to the pinhole
camera of the same intrinsics by :func:`reneus_mi.data.undistort.undistort`, the one
undistortion of the package (pixels the photograph does not cover become black and leave
the mask). Other camera models (fisheye, equirectangular) are refused. An image's alpha
channel is its container mask; frames without alpha get the container's
projection. nerfstudio's per-frame ``mask_path`` (white: pixels the loss may use) is
honoured: the training mask is the container's within it. The ReNeuS keys ``IOR``, ``mesh_outside``, ``mesh_inside`` (and
``scale_mat``) are described in :mod:`reneus_mi.data.dataset`.

The writer puts 8-bit RGBA PNGs (alpha = mask) in ``images/`` and the meshes
beside ``transforms.json``.
"""
from __future__ import annotations

import json
import os

import numpy as np

from reneus_mi.data.cameras import (OPENGL_FROM_OPENCV, check_c2w, check_K, focal_from_fov,
                                    has_skew, intrinsics)
from reneus_mi.data.dataset import Dataset, assemble, read_extras, write_extras
from reneus_mi.data.images import (IMAGE_EXTENSIONS, check_images_fit, holds_8_bits, read_image,
                                   read_mask, reduced_size, resize, stored, write_image)
from reneus_mi.data.undistort import DISTORTION_KEYS, distortion, undistort
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_write_text, load_json

#: Metadata file names, in order of preference.
TRANSFORMS_FILES = ('transforms.json', 'transforms_train.json')

_INTRINSIC_KEYS = ('camera_angle_x', 'camera_angle_y', 'fl_x', 'fl_y', 'cx', 'cy', 'w', 'h',
                   'camera_model', 'k1', 'k2', 'k3', 'k4', 'p1', 'p2')
#: nerfstudio's camera models that are pinholes once the OpenCV distortion is taken out.
_CAMERA_MODELS = ('OPENCV', 'PINHOLE', 'SIMPLE_PINHOLE')


def find(root: str) -> str | None:
    """Path of the dataset's transforms file, or None when it has none."""
    for name in TRANSFORMS_FILES:
        path = os.path.join(root, name)
        if os.path.isfile(path):
            return path
    return None


def _image_path(root: str, file_path: str, where: str) -> str:
    path = os.path.normpath(os.path.join(root, file_path))
    if os.path.isfile(path):
        return path
    for ext in IMAGE_EXTENSIONS:
        if os.path.isfile(path + ext):
            return path + ext
    raise ReneusError(f"{where}: image '{file_path}' is missing (looked for {path} with and "
                     f"without the extensions {', '.join(IMAGE_EXTENSIONS[:6])})")


def _number(cam: dict, key: str, where: str) -> float:
    value = cam[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ReneusError(f"{where}: '{key}' must be a number, got {value!r}")
    return float(value)


def _intrinsics(cam: dict, width: int, height: int, where: str) -> np.ndarray:
    for key, size in (('w', width), ('h', height)):
        if key in cam and _number(cam, key, where) != size:
            raise ReneusError(f"{where}: '{key}' is {cam[key]}, but the image is {width}x{height}")
    if 'fl_x' in cam:
        fx = _number(cam, 'fl_x', where)
        fy = _number(cam, 'fl_y', where) if 'fl_y' in cam else fx
    elif 'camera_angle_x' in cam:
        fx = focal_from_fov(_number(cam, 'camera_angle_x', where), width)
        fy = (focal_from_fov(_number(cam, 'camera_angle_y', where), height)
              if 'camera_angle_y' in cam else fx)
    else:
        raise ReneusError(f"{where}: expected intrinsics 'camera_angle_x' or 'fl_x'")
    cx = _number(cam, 'cx', where) if 'cx' in cam else 0.5 * width
    cy = _number(cam, 'cy', where) if 'cy' in cam else 0.5 * height
    return check_K(intrinsics(fx, fy, cx, cy), where)


def _distortion(cam: dict, where: str):
    """The frame's OpenCV distortion (k1, k2, p1, p2, k3), or None for a pinhole."""
    model = cam.get('camera_model', 'OPENCV')
    if model not in _CAMERA_MODELS:
        raise ReneusError(f"{where}: camera_model {model!r}; expected one of {', '.join(_CAMERA_MODELS)} "
                          "(undistort fisheye photographs to a pinhole first)")
    if 'k4' in cam and _number(cam, 'k4', where) != 0.0:
        raise ReneusError(f"{where}: 'k4' is {cam['k4']}; expected camera_model OPENCV's "
                          f"{', '.join(DISTORTION_KEYS)} only (k4 belongs to fisheye models)")
    values = [_number(cam, k, where) if k in cam else 0.0 for k in DISTORTION_KEYS]
    if not any(values):
        return None
    if model != 'OPENCV':
        raise ReneusError(f"{where}: camera_model {model} with distortion {values}; expected OPENCV "
                          "for a lens with distortion")
    return distortion(values, where)


def read(path: str, *, need_container: bool = True, max_size: int = 0, extra_per_pixel: int = 0) -> Dataset:
    """Read the dataset described by the transforms file ``path``.

    ``max_size`` reduces photographs whose longest side exceeds it (area averaging; the
    cameras follow). Memory is checked from the images' headers before any is decoded
    (``extra_per_pixel``: what the caller will hold besides, see
    :func:`~reneus_mi.data.images.check_images_fit`).
    """
    root = os.path.dirname(os.path.abspath(path))
    meta = load_json(path, 'transforms file')
    frames = meta.get('frames')
    if not isinstance(frames, list) or not frames:
        raise ReneusError(f"{path}: expected a non-empty list 'frames'")
    top = {k: meta[k] for k in _INTRINSIC_KEYS if k in meta}
    files = []
    for i, frame in enumerate(frames):
        where = f"{path}: frames[{i}]"
        if not isinstance(frame, dict) or 'file_path' not in frame or 'transform_matrix' not in frame:
            raise ReneusError(f"{where}: expected 'file_path' and 'transform_matrix'")
        files.append(_image_path(root, str(frame['file_path']), where))
    check_images_fit(files, max_size, path, extra_per_pixel)
    images, masks, keeps, Ks, c2ws = [], [], [], [], []
    for i, (frame, file) in enumerate(zip(frames, files)):
        where = f"{path}: frames[{i}]"
        rgb, alpha = read_image(file)
        eight_bit = holds_8_bits(rgb)
        height, width = rgb.shape[:2]
        keep = _keep_mask(root, frame, (width, height), where)
        cam = {**top, **{k: frame[k] for k in _INTRINSIC_KEYS if k in frame}}
        K = _intrinsics(cam, width, height, where)
        dist = _distortion(cam, where)
        size = reduced_size(width, height, max_size)
        K_out = np.diag([size[0] / width, size[1] / height, 1.0]) @ K
        if dist is not None:
            rgb, covered = undistort(rgb, K, dist, K_out, size)
            alpha, keep = (None if m is None else undistort(m, K, dist, K_out, size)[0] * covered
                           for m in (alpha, keep))
        else:
            rgb, alpha, keep = (None if m is None else resize(m, size) for m in (rgb, alpha, keep))
        Ks.append(K_out)
        try:
            gl = np.asarray(frame['transform_matrix'], dtype=np.float64)
        except (TypeError, ValueError):
            raise ReneusError(f"{where}: 'transform_matrix' must be a 4x4 matrix of numbers") from None
        c2ws.append(check_c2w(gl, f"{where}: transform_matrix") @ OPENGL_FROM_OPENCV)
        images.append(stored(rgb, eight_bit))
        masks.append(None if alpha is None else alpha >= 0.5)  # a reduced pixel half inside is inside
        keeps.append(None if keep is None else keep >= 0.5)
    ds = assemble(images=images, masks=masks, K=np.stack(Ks), c2w=np.stack(c2ws),
                  names=[os.path.basename(f) for f in files], files=files, root=root,
                  meta_file=path, need_container=need_container,
                  mask_sources=['from its alpha channel'] * len(files),
                  **read_extras(meta, root, path))
    for i, keep in enumerate(keeps):
        if keep is not None:
            ds.masks[i] &= keep
    return ds


def _keep_mask(root: str, frame: dict, size: tuple[int, int], where: str) -> np.ndarray | None:
    """nerfstudio's per-frame ``mask_path``: the pixels the loss may use (white), as (H,W)
    float32 at the image's size; the training mask is the container's within it."""
    if 'mask_path' not in frame:
        return None
    mask_file = os.path.normpath(os.path.join(root, str(frame['mask_path'])))
    if not os.path.isfile(mask_file):
        raise ReneusError(f"{where}: mask_path '{frame['mask_path']}' is missing (looked for {mask_file})")
    keep = read_mask(mask_file)
    if keep.shape[::-1] != tuple(size):
        raise ReneusError(f"{where}: mask_path '{frame['mask_path']}' is {keep.shape[1]}x{keep.shape[0]}, "
                          f"but its image is {size[0]}x{size[1]}; expected a mask of the image's size")
    return keep.astype(np.float32)


def write(ds: Dataset, out_dir: str) -> None:
    """Write ``ds`` as ``out_dir/transforms.json`` plus ``images/*.png`` (checked beforehand)."""
    if np.any(has_skew(ds.K)):
        raise ReneusError(f"{ds.root}: K has a skew term, which transforms.json cannot store")
    os.makedirs(os.path.join(out_dir, 'images'), exist_ok=True)
    shared = bool(np.all(ds.K == ds.K[0]))

    def camera(K: np.ndarray) -> dict:
        return {'fl_x': K[0, 0], 'fl_y': K[1, 1], 'cx': K[0, 2], 'cy': K[1, 2],
                'w': ds.width, 'h': ds.height}

    meta = {}
    if shared:
        meta['camera_angle_x'] = float(2.0 * np.arctan(0.5 * ds.width / ds.K[0, 0, 0]))
        meta.update(camera(ds.K[0]))
    meta.update(write_extras(ds, out_dir))
    if ds.scale_mat is not None:
        meta['scale_mat'] = np.asarray(ds.scale_mat).tolist()
    frames = []
    for i, name in enumerate(ds.names):
        file_path = f"images/{os.path.splitext(name)[0]}.png"
        write_image(os.path.join(out_dir, file_path),
                    np.concatenate([ds.image(i), ds.masks[i][..., None]], axis=-1))
        frame = {'file_path': file_path,
                 'transform_matrix': (ds.c2w[i] @ OPENGL_FROM_OPENCV).tolist()}
        if not shared:
            frame.update(camera(ds.K[i]))
        frames.append(frame)
    meta['frames'] = frames
    # Written last and atomically: a folder with transforms.json is a whole dataset.
    atomic_write_text(os.path.join(out_dir, 'transforms.json'),
                      json.dumps(meta, indent=2, default=float))
