"""Checks made before a command computes or writes anything.

- Output paths (:func:`check_output_file`, :func:`check_output_dir`): the
  place must be writable, must not lie in or over a folder holding input data
  (a dataset: photographs and cameras), and an existing file is never
  replaced unless the caller says it may be.
- Sizes (:func:`check_memory`, :func:`check_index_range`): a request that
  would exceed the machine's memory or Dr.Jit's 32-bit indices is refused up
  front with the size it would need, instead of being killed by the kernel.
- Runs (:class:`RunLock`, :func:`repair_log`, :func:`check_npz_file`):
  one process per run folder, a log consistent with its checkpoint, and a
  checkpoint file that is whole.
"""
from __future__ import annotations

import json
import os
import zipfile

from reneus_mi.errors import ReneusError

#: Files that make a folder a dataset (its photographs are irreplaceable).
DATASET_MARKERS = ('transforms.json', 'transforms_train.json', 'cameras_sphere.npz')
#: Share of the physical memory one request may take.
MEMORY_FRACTION = 0.8
#: Dr.Jit indexes arrays with 32-bit unsigned integers.
MAX_INDEX = 2**32 - 1


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
    """``path``'s nearest existing ancestor must be a folder we may write into."""
    folder = path
    while not os.path.exists(folder):
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise ReneusError(f'{what} {path}: {folder} is a file, expected a folder')
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ReneusError(f'{what} {path}: folder {folder} is not writable')


def _check_not_input(path: str, what: str, inputs) -> None:
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
    data = _data_folders(path)
    if data:
        raise ReneusError(f'{what} {path}: lies in the dataset folder {data[-1]}; '
                          'expected a place outside any folder of photographs')


def check_output_file(path: str | os.PathLike, *, inputs=(), overwrite: bool = False,
                      what: str = 'output', extensions: tuple[str, ...] = ()) -> str:
    """Check that the file ``path`` may be written; return its absolute path.

    Refused: an extension not in ``extensions`` (when given), a path that is
    one of ``inputs`` (files or folders) or lies in one, a path inside a dataset
    folder, an existing file unless ``overwrite``, an existing folder, and a
    place that is not writable.
    """
    real = _real(path)
    if extensions and os.path.splitext(real)[1].lower() not in extensions:
        raise ReneusError(f"{what} {path}: expected a file ending in {' or '.join(extensions)}")
    if os.path.isdir(real):
        raise ReneusError(f'{what} {path}: is a folder, expected a file name')
    _check_not_input(real, what, inputs)
    if os.path.exists(real) and not overwrite:
        raise ReneusError(f'{what} {path}: exists; expected a new file name '
                          '(or --overwrite to replace it)')
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
    _check_writable(real, what)
    return real


def physical_memory() -> int:
    """Bytes of physical memory of this machine."""
    return os.sysconf('SC_PHYS_PAGES') * os.sysconf('SC_PAGE_SIZE')


def format_bytes(n: float) -> str:
    for unit in ('B', 'KiB', 'MiB', 'GiB', 'TiB', 'PiB'):
        if abs(n) < 1024 or unit == 'PiB':
            return f'{n:.3g} {unit}'
        n /= 1024
    raise AssertionError('unreachable')


def check_memory(n_bytes: float, what: str, *, available: int | None = None) -> None:
    """Refuse a request for ``n_bytes`` above :data:`MEMORY_FRACTION` of the memory."""
    limit = MEMORY_FRACTION * (physical_memory() if available is None else available)
    if n_bytes > limit:
        raise ReneusError(f'{what}: needs about {format_bytes(n_bytes)}, but this machine has '
                          f'{format_bytes(limit / MEMORY_FRACTION)} of memory; expected a smaller value')


def check_index_range(count: int, what: str) -> None:
    """Refuse ``count`` elements in one Dr.Jit array (32-bit indices)."""
    if count > MAX_INDEX:
        raise ReneusError(f'{what}: {count} elements in one array exceed the 32-bit index '
                          f'limit {MAX_INDEX}; expected a smaller value')


#: Bytes per sample along a ray while training: positions, directions, the
#: field's activations kept for the backward pass (width x layers x float32,
#: twice for their gradients) and the colours and weights; estimated on the
#: CPU (a 1024-ray batch of the demo field) with a margin of 2.
def training_bytes(batch_rays: int, samples_per_segment: int, segments: int, width: int,
                   layers: int) -> int:
    """Rough peak memory of one training step (see the comment above)."""
    per_sample = 4 * (16 + 2 * width * (layers + 2))
    return 2 * batch_rays * samples_per_segment * segments * per_sample


class RunLock:
    """An exclusive lock on a run folder, so that two processes never drive one run.

    The lock file holds the owner's process id; a lock whose process is gone
    (a kill) is taken over. Use as a context manager.
    """

    NAME = '.lock'

    def __init__(self, folder: str | os.PathLike):
        self.path = os.path.join(os.fspath(folder), self.NAME)
        self.held = False

    def acquire(self) -> None:
        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                owner = self._owner()
                if owner is not None and _alive(owner):
                    raise ReneusError(f'{os.path.dirname(self.path)}: run is in use by process '
                                      f'{owner}; expected one process per run folder') from None
                # The owner is gone: the lock is stale.
                try:
                    os.unlink(self.path)
                except FileNotFoundError:
                    pass
                continue
            with os.fdopen(fd, 'w') as f:
                f.write(str(os.getpid()))
            self.held = True
            return
        raise ReneusError(f'{self.path}: cannot take the run lock')

    def _owner(self) -> int | None:
        try:
            with open(self.path) as f:
                return int(f.read().strip() or 0) or None
        except (OSError, ValueError):
            return None

    def release(self) -> None:
        if self.held:
            self.held = False
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def repair_log(path: str | os.PathLike, iteration: int) -> list[dict]:
    """Keep the log lines of steps ``1..iteration`` (a checkpoint's); return them.

    Lines after the checkpoint (a resumed run redoes those steps) and a torn
    last line (a kill mid-write) are dropped. A torn line elsewhere, or a
    missing step before ``iteration``, is an error that names the step.
    """
    from reneus_mi.io import atomic_write_text
    path = os.fspath(path)
    if not os.path.isfile(path):
        if iteration > 0:
            raise ReneusError(f'{path}: log is missing, but the checkpoint is at step {iteration}; '
                              'expected one log line per step')
        return []
    with open(path) as f:
        lines = [line for line in f.read().split('\n') if line.strip()]
    entries = []
    for n, line in enumerate(lines):
        try:
            entry = json.loads(line)
            step = int(entry['iteration'])
        except (ValueError, KeyError, TypeError):
            if n == len(lines) - 1:
                break  # torn by a kill while writing
            raise ReneusError(f'{path}: line {n + 1} is not a log entry ({line[:40]!r}); '
                              "expected JSON with an 'iteration'") from None
        if step <= iteration:
            entries.append(entry)
    steps = [e['iteration'] for e in entries]
    if steps != list(range(1, iteration + 1)):
        missing = sorted(set(range(1, iteration + 1)) - set(steps))
        raise ReneusError(f'{path}: log lacks steps {missing[:5]}{" ..." if len(missing) > 5 else ""}'
                          f' (or repeats some) before the checkpoint step {iteration}; '
                          'expected one line per step')
    atomic_write_text(path, ''.join(json.dumps(e) + '\n' for e in entries))
    return entries


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


def remove_stray_temporaries(folder: str | os.PathLike) -> list[str]:
    """Delete the temporaries an atomic write left behind when it was killed."""
    from reneus_mi.io import is_temporary
    folder = os.fspath(folder)
    removed = []
    if os.path.isdir(folder):
        for name in os.listdir(folder):
            if is_temporary(name):
                os.unlink(os.path.join(folder, name))
                removed.append(name)
    return removed
