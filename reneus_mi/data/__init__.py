"""Datasets in and out: NeRF/Blender ``transforms.json`` and NeuS ``cameras_sphere.npz``.

:func:`load_dataset` detects the format of a folder and returns a
:class:`Dataset`; :func:`write_dataset` writes one in either format. The
formats are described in :mod:`reneus_mi.data.blender` and
:mod:`reneus_mi.data.neus_format`, the ReNeuS keys they share in
:mod:`reneus_mi.data.dataset`.
"""
from __future__ import annotations

import os

from reneus_mi.data import blender
from reneus_mi.data import neus_format as neus
from reneus_mi.data.dataset import Dataset, check_writable
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError

FORMATS = {'blender': blender, 'neus': neus}

__all__ = ['Dataset', 'load_dataset', 'write_dataset', 'FORMATS']


def load_dataset(path: str, *, need_container: bool = True, max_size: int = 0,
                 extra_per_pixel: int = 0) -> Dataset:
    """Read the dataset in folder ``path`` (or named by its metadata file).

    The format is detected: a ``transforms.json`` (or ``transforms_train.json``)
    means Blender, a ``cameras_sphere.npz`` means NeuS. With ``need_container``
    a dataset without a container mesh is an error; without it, views lacking
    a mask get an all-True one. Photographs larger than ``max_size`` pixels on
    a side are reduced as they load (0: as they are); their memory, and the
    ``extra_per_pixel`` bytes a caller holds besides, is checked before any is
    decoded.
    """
    if os.path.basename(path) in (*blender.TRANSFORMS_FILES, neus.CAMERAS_FILE):
        path = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(path):
        raise ReneusError(f"{path}: dataset folder is missing (expected a folder with "
                         f"{blender.TRANSFORMS_FILES[0]} or {neus.CAMERAS_FILE})")
    for module in (blender, neus):
        found = module.find(path)
        if found is not None:
            return module.read(found, need_container=need_container, max_size=max_size,
                               extra_per_pixel=extra_per_pixel)
    raise ReneusError(f"{path}: unknown dataset format (expected {blender.TRANSFORMS_FILES[0]} "
                     f"or {neus.CAMERAS_FILE} in the folder)")


def write_dataset(ds: Dataset, out_dir: str, fmt: str) -> None:
    """Write ``ds`` into folder ``out_dir`` as ``fmt`` ('blender' or 'neus').

    Images become 8-bit PNGs and the meshes are copied beside the metadata.
    ``out_dir`` must be new or empty. Everything is checked before the first
    file is written.
    """
    if fmt not in FORMATS:
        raise ReneusError(f"format {fmt!r}: expected one of {', '.join(FORMATS)}")
    check_writable(ds, out_dir)
    # Never over files this call did not write: the folder is new or empty.
    guards.check_output_dir(out_dir, what='dataset folder')
    os.makedirs(out_dir, exist_ok=True)
    FORMATS[fmt].write(ds, out_dir)
