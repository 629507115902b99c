"""Files written atomically (a kill never leaves a torn file behind), and read back whole.

Every writer of the package goes through :func:`atomic_path`: the data goes to
a temporary file beside the target (same folder, so the rename is atomic; same
extension, so writers that pick the format by extension still work), which is
renamed over the target once complete, and removed if the write fails. The
temporary is created with the mode any new file gets (0666 less the umask: 0644
under the usual 022), not ``tempfile``'s owner-only 0600, so that a team sharing
a drive can read what a run wrote.
"""
from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import tempfile
import zipfile

import mitsuba as mi
import numpy as np

from reneus_mi.utils import interrupt
from reneus_mi.utils.errors import ReneusError

#: The name of every temporary of :func:`atomic_path` starts so (a kill may leave one behind).
TEMPORARY_PREFIX = '.tmp-'


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; on success rename it over ``path``.

    The temporary goes if the write fails or the command is interrupted
    (:func:`reneus_mi.utils.interrupt.temporary`); a failed write (a full disk) names ``path``.
    """
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    tmp = _new_temporary(directory, os.path.splitext(path)[1])
    with interrupt.temporary(tmp), _naming(path, tmp):
        yield tmp
        os.replace(tmp, path)


@contextlib.contextmanager
def _naming(path: str, tmp: str):
    """Errors of a write name the file written, never its temporary or nothing at all."""
    try:
        yield
    except OSError as e:
        if e.filename in (None, tmp):
            raise OSError(e.errno, e.strerror or str(e), path) from None
        raise


def _new_temporary(directory: str, suffix: str) -> str:
    """Create an empty, new temporary file in ``directory``; the umask sets its mode."""
    while True:
        tmp = os.path.join(directory, f'{TEMPORARY_PREFIX}{secrets.token_hex(6)}{suffix}')
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike):
    """Yield a temporary folder beside ``path``; on success it becomes ``path``, whole.

    An empty folder at ``path``, or one the caller owns (an earlier copy it wrote), is
    replaced. A failure or an interrupt removes the temporary: ``path`` is never left half
    written. The folder gets the permissions of any new folder (the umask).
    """
    path = os.path.abspath(os.fspath(path))
    parent = os.path.dirname(path)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(dir=parent, prefix=TEMPORARY_PREFIX)
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o777 & ~mask)
    with interrupt.temporary(tmp), _naming(path, tmp):
        yield tmp
        if os.path.isdir(path) and os.listdir(path):
            with interrupt.temporary(tempfile.mkdtemp(dir=parent, prefix=TEMPORARY_PREFIX)) as old:
                os.replace(path, os.path.join(old, 'replaced'))
                os.replace(tmp, path)
                shutil.rmtree(old)
        else:
            os.replace(tmp, path)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = 'wb'):
    """Open a temporary file beside ``path``; on success rename it over ``path``."""
    with atomic_path(path) as tmp, open(tmp, mode) as f:
        yield f


def atomic_mitsuba_write(path: str | os.PathLike, write) -> None:
    """Write with one of Mitsuba's writers (``write(stream)``, e.g. ``bitmap.write`` or
    ``mesh.write_ply``) through a Python file: Mitsuba's file streams do not report a full
    disk, Python's do (naming ``path``)."""
    stream = mi.MemoryStream()
    write(stream)
    with atomic_open(path, 'wb') as f:
        f.write(bytes(stream.raw_buffer()))


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
    return os.path.basename(name).startswith(TEMPORARY_PREFIX)


def load_json(path: str | os.PathLike, what: str = 'file') -> dict:
    """A JSON object from ``path`` (UTF-8, with or without the byte-order mark that Windows
    editors write), or one line naming the file and the fault."""
    path = os.fspath(path)
    try:
        with open(path, encoding='utf-8-sig') as f:
            data = json.load(f)
    except OSError as e:
        raise ReneusError(f'{path}: cannot read the {what} ({e.strerror})') from None
    except ValueError as e:
        raise ReneusError(f'{path}: {what} is not valid JSON ({e})') from None
    if not isinstance(data, dict):
        raise ReneusError(f'{path}: {what}: expected a JSON object')
    return data


def check_npz_file(path: str | os.PathLike, what: str = 'checkpoint', keys=('meta',)) -> None:
    """Refuse a missing, truncated or foreign ``.npz`` (a checkpoint, a saved field) in one line.

    ``keys`` are arrays the file must hold (a checkpoint's ``meta``).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ReneusError(f'{path}: {what} file does not exist')
    try:
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
            names = z.namelist()
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise ReneusError(f'{path}: not a whole {what} (truncated, or not an .npz: {e}); '
                          'expected a file written by reneus-mi') from None
    if bad is not None:
        raise ReneusError(f'{path}: {what} is corrupt (entry {bad}); expected a whole file')
    absent = [k for k in keys if f'{k}.npy' not in names]
    if absent:
        raise ReneusError(f"{path}: not a reneus-mi {what} (no {', '.join(absent)}); "
                          'expected a file written by reneus-mi')


def read_json(path: str | os.PathLike):
    """The JSON value in ``path``, None where the file is missing or unreadable (what a report
    reads from folders that may hold it)."""
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None
