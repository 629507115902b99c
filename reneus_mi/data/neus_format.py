"""NeuS/IDR datasets: ``cameras_sphere.npz`` with ``image/`` and ``mask/``.

Layout::

    DATA_DIR/cameras_sphere.npz   world_mat_i (K [R|t], 4x4), scale_mat_i (4x4)
    DATA_DIR/image/<i>.png        view i: the number in the name is the i of
                                  world_mat_i (0.png, 000.png, r_000.png ...)
    DATA_DIR/mask/<i>.png         optional container masks, numbered alike
    DATA_DIR/reneus.json          optional: {"IOR": 1.45,
                                             "mesh_outside": "container.ply",
                                             "mesh_inside": "gt_mesh.ply"}

Views are paired with cameras by the number in the file name, never by the
text order of the names (``10.png`` sorts before ``2.png``): every image must
carry exactly one number, the numbers must be distinct and exactly
``0 ... N-1`` of the camera file's ``world_mat_i``; anything else (``1.png``
beside ``01.png``, a name without a number, a gap) is an error.

``world_mat_i`` maps world coordinates (those of the meshes) to pixels;
``scale_mat_i`` maps NeuS's unit sphere to world coordinates and must be the
same for every view. ``reneus.json`` holds what the NeuS format has no field
for (see :mod:`reneus_mi.data.dataset`); without ``mask/`` the masks are the
container's projection.
"""
from __future__ import annotations

import json
import os
import re
import zipfile

import numpy as np

from reneus_mi.data.cameras import compose_projection, decompose_projection
from reneus_mi.data.dataset import Dataset, assemble, read_extras, write_extras
from reneus_mi.data.images import (IMAGE_EXTENSIONS, check_images_fit, holds_8_bits, read_image,
                                   read_mask, reduced_size, resize, stored, write_image)
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_savez, atomic_write_text, load_json

CAMERAS_FILE = 'cameras_sphere.npz'
META_FILE = 'reneus.json'


def find(root: str) -> str | None:
    """Path of the dataset's camera file, or None when it has none."""
    path = os.path.join(root, CAMERAS_FILE)
    return path if os.path.isfile(path) else None


def _list_images(folder: str) -> list[str]:
    return sorted(os.path.join(folder, f) for f in os.listdir(folder)
                  if os.path.splitext(f)[1] in IMAGE_EXTENSIONS)


def view_files(folder: str, n: int, cameras: str) -> list[str]:
    """The image files of ``folder`` in view order 0 ... n-1, by the number in each name.

    ``cameras`` (the camera file) is named in the messages. Raises unless the
    names carry the numbers 0 ... n-1, once each.
    """
    by_index: dict[int, str] = {}
    for path in _list_images(folder):
        name = os.path.basename(path)
        numbers = re.findall(r'\d+', os.path.splitext(name)[0])
        if len(numbers) != 1:
            raise ReneusError(f"{path}: expected exactly one view number in the file name "
                              f"(like 0.png or r_012.png, matching world_mat_i of {cameras}), "
                              f"found {len(numbers)}")
        i = int(numbers[0])
        if i in by_index:
            raise ReneusError(f"{folder}: {os.path.basename(by_index[i])} and {name} both "
                              f"name view {i}; expected one file per view")
        by_index[i] = path
    if sorted(by_index) != list(range(n)):
        extra = sorted(set(by_index) - set(range(n)))
        missing = sorted(set(range(n)) - set(by_index))
        raise ReneusError(f"{folder}: has {len(by_index)} images, but {cameras} has {n} cameras; "
                          f"expected the numbers 0 ... {n - 1} of world_mat_i in the file names: "
                          f"missing {missing[:5]}, unexpected {extra[:5]}")
    return [by_index[i] for i in range(n)]


def _load_npz(path: str) -> dict:
    try:
        with np.load(path) as npz:
            return {k: np.asarray(npz[k]) for k in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        raise ReneusError(f"{path}: unreadable camera file ({err})") from None


def read(path: str, *, need_container: bool = True, max_size: int = 0, extra_per_pixel: int = 0) -> Dataset:
    """Read the dataset whose ``cameras_sphere.npz`` is ``path`` (``max_size``,
    ``extra_per_pixel``: as :func:`reneus_mi.data.blender.read`)."""
    root = os.path.dirname(os.path.abspath(path))
    cams = _load_npz(path)
    n = len([k for k in cams if re.fullmatch(r'world_mat_\d+', k)])
    absent = [f'world_mat_{i}' for i in range(n) if f'world_mat_{i}' not in cams]
    if n == 0 or absent:
        raise ReneusError(f"{path}: expected world_mat_0 ... world_mat_{max(n - 1, 0)}, "
                         f"missing {absent or ['world_mat_0']}")
    image_dir = os.path.join(root, 'image')
    if not os.path.isdir(image_dir):
        raise ReneusError(f"{image_dir}: image folder is missing")
    files = view_files(image_dir, n, path)
    mask_dir = os.path.join(root, 'mask')
    mask_files = view_files(mask_dir, n, path) if os.path.isdir(mask_dir) else None

    check_images_fit(files, max_size, path, extra_per_pixel)
    Ks, c2ws = zip(*(decompose_projection(cams[f'world_mat_{i}'], f"{path}: world_mat_{i}")
                     for i in range(n)))
    scale_mat = None
    if 'scale_mat_0' in cams:
        scale_mat = np.asarray(cams['scale_mat_0'], np.float64)
        for i in range(n):
            other = cams.get(f'scale_mat_{i}')
            if other is None or other.shape != (4, 4) or not np.allclose(other, scale_mat):
                raise ReneusError(f"{path}: scale_mat_{i}: expected a 4x4 matrix equal to "
                                 "scale_mat_0 (one normalisation for all views)")

    meta_path = os.path.join(root, META_FILE)
    meta = {}
    if os.path.isfile(meta_path):
        meta = load_json(meta_path, 'NeuS meta file')
    extras = read_extras(meta, root, meta_path)
    if scale_mat is not None:
        extras['scale_mat'] = scale_mat
    images, masks, scaled = [], [], []
    for i, file in enumerate(files):
        rgb = read_image(file)[0]
        height, width = rgb.shape[:2]
        size = reduced_size(width, height, max_size)
        images.append(stored(resize(rgb, size), holds_8_bits(rgb)))
        scaled.append(np.diag([size[0] / width, size[1] / height, 1.0]) @ Ks[i])
        if mask_files:
            mask = read_mask(mask_files[i])
            if mask.shape == (height, width) and size != (width, height):
                mask = resize(mask.astype(np.float32), size) >= 0.5  # half inside is inside
            masks.append(mask)
    return assemble(images=images, masks=masks if mask_files else [None] * n,
                    K=np.stack(scaled), c2w=np.stack(c2ws), names=[os.path.basename(f) for f in files],
                    files=files, root=root, meta_file=meta_path, need_container=need_container,
                    mask_sources=mask_files and [f'from {f}' for f in mask_files], **extras)


def write(ds: Dataset, out_dir: str) -> None:
    """Write ``ds`` in the NeuS layout into ``out_dir`` (checked beforehand).

    Views are named ``000.png``, ``001.png`` ...: the number is the view's
    index (see the module docstring).
    """
    stems = [f'{i:03d}' for i in range(len(ds))]
    for sub in ('image', 'mask'):
        folder = os.path.join(out_dir, sub)
        stale = (set(map(os.path.basename, _list_images(folder))) - {f'{s}.png' for s in stems}
                 if os.path.isdir(folder) else set())
        if stale:
            raise ReneusError(f"{folder}: holds other images ({', '.join(sorted(stale)[:3])}...) "
                             "that NeuS would take for views; write into an empty folder")
    if ds.scale_mat is not None:
        scale_mat = np.asarray(ds.scale_mat, np.float64)
    else:
        # NeuS needs a normalisation; the container's bounding sphere is the natural one.
        scale_mat = np.eye(4)
        if ds.container is not None:
            centre, radius = ds.normalization()
            scale_mat[:3, :3] *= radius
            scale_mat[:3, 3] = centre
    for sub in ('image', 'mask'):
        os.makedirs(os.path.join(out_dir, sub), exist_ok=True)
    for i, stem in enumerate(stems):
        write_image(os.path.join(out_dir, 'image', f'{stem}.png'), ds.image(i))
        write_image(os.path.join(out_dir, 'mask', f'{stem}.png'), ds.masks[i].astype(np.float32))
    cams = {}
    for i in range(len(ds)):
        cams[f'world_mat_{i}'] = compose_projection(ds.K[i], ds.c2w[i])
        cams[f'scale_mat_{i}'] = scale_mat
    meta = write_extras(ds, out_dir)
    if meta:
        atomic_write_text(os.path.join(out_dir, META_FILE), json.dumps(meta, indent=2))
    # Written last and atomically: a folder with the camera file is a whole dataset.
    atomic_savez(os.path.join(out_dir, CAMERAS_FILE), **cams)
