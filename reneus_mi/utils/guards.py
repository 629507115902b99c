"""Output paths, checked before a command writes anything.

A place to write (:func:`check_output_file`, :func:`check_output_dir`) must be
writable, must not lie in or over a folder holding input data (a dataset:
photographs and cameras) or one of the command's inputs, and an existing file
is never replaced unless the caller says it may be. Sizes are checked by
:mod:`reneus_mi.utils.limits`, run folders by :mod:`reneus_mi.train.run_folder`.
"""
from __future__ import annotations

import os

from reneus_mi.utils.errors import ReneusError

#: Files that make a folder a dataset (its photographs are irreplaceable).
DATASET_MARKERS = ('transforms.json', 'transforms_train.json', 'cameras_sphere.npz')


def _real(path: str | os.PathLike) -> str:
    return os.path.realpath(os.path.abspath(os.fspath(path)))


def _within(path: str, folder: str) -> bool:
    """Whether ``path`` is ``folder`` or lies below it (both real paths)."""
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def is_dataset_dir(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` holds a dataset's metadata file."""
    return any(os.path.isfile(os.path.join(folder, m)) for m in DATASET_MARKERS)


def _data_folders(path: str) -> list[str]:
    """Dataset folders among ``path`` and its ancestors (real paths)."""
    found, folder = [], path
    while True:
        if os.path.isdir(folder) and is_dataset_dir(folder):
            found.append(folder)
        parent = os.path.dirname(folder)
        if parent == folder:
            return found
        folder = parent


def _check_writable(path: str, what: str) -> None:
    """``path``'s nearest existing ancestor folder must be one we may write into."""
    folder = os.path.dirname(path)
    while not os.path.exists(folder):
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise ReneusError(f'{what} {path}: {folder} is a file, expected a folder')
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ReneusError(f'{what} {path}: folder {folder} is not writable')


def _check_not_input(path: str, what: str, inputs) -> None:
    data = _data_folders(path)
    if data:
        raise ReneusError(f'{what} {path}: lies in the dataset folder {data[-1]}; '
                          'expected a place outside any folder of photographs')
    for given in inputs or ():
        if given is None:
            continue
        src = _real(given)
        if _within(path, src):
            raise ReneusError(f'{what} {path}: is or lies inside the input {given}; '
                              'expected a place apart from the input data')
        if os.path.isdir(src) and _within(src, path):
            raise ReneusError(f'{what} {path}: contains the input {given}; '
                              'expected a place apart from the input data')


def check_output_file(path: str | os.PathLike, *, inputs=(), overwrite: bool = False,
                      what: str = 'output', extensions: tuple[str, ...] = (),
                      overwrite_flag: str | None = '--overwrite') -> str:
    """Check that the file ``path`` may be written; return its absolute path.

    Refused: an extension not in ``extensions`` (when given), a path that is
    one of ``inputs`` (files or folders) or lies in one, a path inside a dataset
    folder, an existing file unless ``overwrite`` (the message names the command's
    ``overwrite_flag``; None: it has none), an existing folder, and a place that is not
    writable.
    """
    real = _real(path)
    _check_not_input(real, what, inputs)
    if extensions and os.path.splitext(real)[1].lower() not in extensions:
        raise ReneusError(f"{what} {path}: expected a file ending in {' or '.join(extensions)}")
    if os.path.isdir(real):
        raise ReneusError(f'{what} {path}: is a folder, expected a file name')
    if os.path.exists(real) and not overwrite:
        replace = f'or {overwrite_flag} to replace it' if overwrite_flag else 'or move that file away first'
        raise ReneusError(f'{what} {path}: exists; expected a new file name ({replace})')
    _check_writable(real, what)
    return real


def check_output_dir(path: str | os.PathLike, *, inputs=(), allow: tuple[str, ...] = (),
                     what: str = 'output folder') -> str:
    """Check that the folder ``path`` may be written into; return its absolute path.

    The folder must be new or empty, or hold only names in ``allow`` (files
    this command wrote before, e.g. a run it continues); it must not be,
    contain or lie in one of ``inputs`` or a dataset folder; it must be
    writable.
    """
    real = _real(path)
    if os.path.exists(real) and not os.path.isdir(real):
        raise ReneusError(f'{what} {path}: is a file, expected a folder')
    _check_not_input(real, what, inputs)
    if os.path.isdir(real):
        if is_dataset_dir(real):
            raise ReneusError(f'{what} {path}: holds a dataset; expected a new or empty folder')
        foreign = sorted(set(os.listdir(real)) - set(allow))
        if foreign:
            raise ReneusError(f"{what} {path}: is not empty (holds {', '.join(foreign[:3])}"
                              f"{' ...' if len(foreign) > 3 else ''}); expected a new or empty "
                              'folder, so that no file is overwritten')
    _check_writable(os.path.join(real, '.'), what)
    return real
