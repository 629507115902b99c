"""Atomic file writes: a kill never leaves a torn file behind.

Every writer of the package goes through :func:`atomic_path`: the data goes to
a temporary file beside the target (same folder, so the rename is atomic; same
extension, so writers that pick the format by extension still work), which is
renamed over the target once complete, and removed if the write fails.
"""
from __future__ import annotations

import contextlib
import os
import tempfile

import numpy as np


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; on success rename it over ``path``."""
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=directory, prefix='.tmp-', suffix=os.path.splitext(path)[1])
    os.close(fd)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = 'wb'):
    """Open a temporary file beside ``path``; on success rename it over ``path``."""
    with atomic_path(path) as tmp, open(tmp, mode) as f:
        yield f


def atomic_savez(path: str | os.PathLike, **arrays) -> None:
    with atomic_open(path, 'wb') as f:
        np.savez(f, **arrays)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_open(path, 'w') as f:
        f.write(text)


def write_section(path: str | os.PathLike, name: str, text: str) -> None:
    """Put ``text`` in the file's section ``name`` (between ``<!-- name -->`` and
    ``<!-- /name -->``), keeping the rest: several benchmarks can share one document."""
    start, end = f'<!-- {name} -->', f'<!-- /{name} -->'
    old = ''
    if os.path.isfile(path):
        with open(path) as f:
            old = f.read()
    block = f'{start}\n{text.rstrip()}\n{end}'
    if start in old and end in old:
        new = old[:old.index(start)] + block + old[old.index(end) + len(end):]
    else:
        new = (old.rstrip() + '\n\n' if old.strip() else '') + block + '\n'
    atomic_write_text(path, new)


def atomic_export(mesh, path: str | os.PathLike) -> None:
    """Write a trimesh mesh (the format follows ``path``'s extension)."""
    with atomic_path(path) as tmp:
        mesh.export(tmp)


def is_temporary(name: str) -> bool:
    """Whether a file name is one of :func:`atomic_path`'s temporaries (left by a kill)."""
    return os.path.basename(name).startswith('.tmp-')
