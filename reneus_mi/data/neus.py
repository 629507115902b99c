"""NeuS/IDR datasets: ``cameras_sphere.npz`` with ``image/`` and ``mask/``.

Layout::

    DATA_DIR/cameras_sphere.npz   world_mat_i (K [R|t], 4x4), scale_mat_i (4x4)
    DATA_DIR/image/*.png          view i is the i-th file in sorted order
    DATA_DIR/mask/*.png           optional container masks, same order
    DATA_DIR/reneus.json          optional: {"IOR": 1.45,
                                             "mesh_outside": "container.ply",
                                             "mesh_inside": "gt_mesh.ply"}

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
from reneus_mi.data.images import IMAGE_EXTENSIONS, read_image, read_mask, write_png

CAMERAS_FILE = 'cameras_sphere.npz'
META_FILE = 'reneus.json'


def find(root: str) -> str | None:
    """Path of the dataset's camera file, or None when it has none."""
    path = os.path.join(root, CAMERAS_FILE)
    return path if os.path.isfile(path) else None


def _list_images(folder: str) -> list[str]:
    return sorted(os.path.join(folder, f) for f in os.listdir(folder)
                  if os.path.splitext(f)[1] in IMAGE_EXTENSIONS)


def _load_npz(path: str) -> dict:
    try:
        with np.load(path) as npz:
            return {k: np.asarray(npz[k]) for k in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        raise ValueError(f"{path}: unreadable camera file ({err})") from None


def read(path: str, *, need_container: bool = True) -> Dataset:
    """Read the dataset whose ``cameras_sphere.npz`` is ``path``."""
    root = os.path.dirname(os.path.abspath(path))
    cams = _load_npz(path)
    n = len([k for k in cams if re.fullmatch(r'world_mat_\d+', k)])
    absent = [f'world_mat_{i}' for i in range(n) if f'world_mat_{i}' not in cams]
    if n == 0 or absent:
        raise ValueError(f"{path}: expected world_mat_0 ... world_mat_{max(n - 1, 0)}, "
                         f"missing {absent or ['world_mat_0']}")
    image_dir = os.path.join(root, 'image')
    if not os.path.isdir(image_dir):
        raise ValueError(f"{image_dir}: image folder is missing")
    files = _list_images(image_dir)
    if len(files) != n:
        raise ValueError(f"{image_dir}: has {len(files)} images, but {path} has {n} cameras")
    mask_dir = os.path.join(root, 'mask')
    mask_files = _list_images(mask_dir) if os.path.isdir(mask_dir) else None
    if mask_files is not None and len(mask_files) != n:
        raise ValueError(f"{mask_dir}: has {len(mask_files)} masks, but {path} has {n} cameras")

    Ks, c2ws = zip(*(decompose_projection(cams[f'world_mat_{i}'], f"{path}: world_mat_{i}")
                     for i in range(n)))
    scale_mat = None
    if 'scale_mat_0' in cams:
        scale_mat = np.asarray(cams['scale_mat_0'], np.float64)
        for i in range(n):
            other = cams.get(f'scale_mat_{i}')
            if other is None or other.shape != (4, 4) or not np.allclose(other, scale_mat):
                raise ValueError(f"{path}: scale_mat_{i}: expected a 4x4 matrix equal to "
                                 "scale_mat_0 (one normalisation for all views)")

    meta_path = os.path.join(root, META_FILE)
    meta = {}
    if os.path.isfile(meta_path):
        try:
            with open(meta_path) as f:
                meta = json.load(f)
        except (OSError, json.JSONDecodeError) as err:
            raise ValueError(f"{meta_path}: unreadable JSON ({err})") from None
        if not isinstance(meta, dict):
            raise ValueError(f"{meta_path}: expected a JSON object")
    extras = read_extras(meta, root, meta_path)
    if scale_mat is not None:
        extras['scale_mat'] = scale_mat
    return assemble(images=[read_image(f)[0] for f in files],
                    masks=([read_mask(f) for f in mask_files] if mask_files
                           else [None] * n),
                    K=np.stack(Ks), c2w=np.stack(c2ws), names=[os.path.basename(f) for f in files],
                    files=files, root=root, meta_file=meta_path, need_container=need_container,
                    **extras)


def write(ds: Dataset, out_dir: str) -> None:
    """Write ``ds`` in the NeuS layout into ``out_dir`` (checked beforehand).

    Views are renamed ``000.png``, ``001.png`` ... unless their names already
    sort in view order, because NeuS orders views by file name.
    """
    stems = [os.path.splitext(name)[0] for name in ds.names]
    if sorted(f'{s}.png' for s in stems) != [f'{s}.png' for s in stems]:
        stems = [f'{i:03d}' for i in range(len(ds))]
    for sub in ('image', 'mask'):
        folder = os.path.join(out_dir, sub)
        stale = (set(map(os.path.basename, _list_images(folder))) - {f'{s}.png' for s in stems}
                 if os.path.isdir(folder) else set())
        if stale:
            raise ValueError(f"{folder}: holds other images ({', '.join(sorted(stale)[:3])}...) "
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
        write_png(os.path.join(out_dir, 'image', f'{stem}.png'), ds.images[i])
        write_png(os.path.join(out_dir, 'mask', f'{stem}.png'), ds.masks[i].astype(np.float32))
    cams = {}
    for i in range(len(ds)):
        cams[f'world_mat_{i}'] = compose_projection(ds.K[i], ds.c2w[i])
        cams[f'scale_mat_{i}'] = scale_mat
    np.savez(os.path.join(out_dir, CAMERAS_FILE), **cams)
    meta = write_extras(ds, out_dir)
    if meta:
        with open(os.path.join(out_dir, META_FILE), 'w') as f:
            json.dump(meta, f, indent=2)
