"""Atomic file writes: a kill never leaves a torn file behind."""
from __future__ import annotations

import contextlib
import os
import tempfile

import numpy as np


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = 'wb'):
    """Open a temporary file beside ``path``; on success rename it over ``path``."""
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=directory, suffix='.tmp')
    try:
        with os.fdopen(fd, mode) as f:
            yield f
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_savez(path: str | os.PathLike, **arrays) -> None:
    with atomic_open(path, 'wb') as f:
        np.savez(f, **arrays)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_open(path, 'w') as f:
        f.write(text)
