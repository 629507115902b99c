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

from reneus_mi import limits
from reneus_mi.errors import ReneusError

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
                      what: str = 'output', extensions: tuple[str, ...] = ()) -> str:
    """Check that the file ``path`` may be written; return its absolute path.

    Refused: an extension not in ``extensions`` (when given), a path that is
    one of ``inputs`` (files or folders) or lies in one, a path inside a dataset
    folder, an existing file unless ``overwrite``, an existing folder, and a
    place that is not writable.
    """
    real = _real(path)
    _check_not_input(real, what, inputs)
    if extensions and os.path.splitext(real)[1].lower() not in extensions:
        raise ReneusError(f"{what} {path}: expected a file ending in {' or '.join(extensions)}")
    if os.path.isdir(real):
        raise ReneusError(f'{what} {path}: is a folder, expected a file name')
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
    _check_writable(os.path.join(real, '.'), what)
    return real


#: Names a run folder holds (see :mod:`reneus_mi.train.trainer`); ``data`` is the demo's dataset.
RUN_FILES = ('config.json', 'log.jsonl', 'checkpoint.npz', 'mesh.ply', 'images', 'meshes', 'data',
             '.lock')


def check_run_dir(path: str | os.PathLike, *, inputs=(), resume: bool = False) -> str:
    """Check a reconstruction's output folder; return its absolute path.

    Apart from the inputs and any dataset folder (:func:`check_output_dir`);
    a new run needs a new or empty folder, or one holding only what a run
    writes (a run killed before its first checkpoint, which starts over);
    ``resume`` accepts whatever the run folder holds.
    """
    from reneus_mi.io import is_temporary
    real = _real(path)
    present = os.listdir(real) if os.path.isdir(real) else []
    allow = present if resume else [n for n in present
                                    if (n in RUN_FILES and n != 'checkpoint.npz') or is_temporary(n)]
    return check_output_dir(path, inputs=inputs, allow=allow, what='output folder')


def check_batch(batch_rays: int, model, what: str = '--batch-rays') -> None:
    """Refuse a ray batch whose samples exceed 32-bit indices or the machine's memory.

    ``model`` is the integrator's :class:`~reneus_mi.config.ModelConfig` (samples per
    segment, D_re).
    """
    samples = model.sampler.n_coarse + model.sampler.n_fine + 1
    segments = model.render.max_depth + 1
    label = f'{what} {batch_rays} ({samples} samples per segment, {segments} segments)'
    limits.check_index_range(batch_rays * samples * segments, label)
    limits.check_memory(training_bytes(batch_rays, samples, segments), label)


def check_field_reaches(center, scale: float, lo, hi, where: str) -> None:
    """Refuse a field sphere (``center``, radius ``scale``) that misses the box ``[lo, hi]``.

    The field lives in that sphere and the rays that matter run inside the
    container: if the two do not meet, no ray reaches the field and training
    has nothing to fit.
    """
    import numpy as np
    c, lo, hi = (np.asarray(v, dtype=np.float64) for v in (center, lo, hi))
    gap = float(np.linalg.norm(np.maximum(lo - c, 0.0) + np.maximum(c - hi, 0.0)))
    if not scale > 0 or gap >= scale:
        raise ReneusError(f'{where}: the field sphere (centre {np.round(c, 4).tolist()}, radius '
                          f'{scale:.4g}) does not meet the container (bounds {np.round(lo, 4).tolist()}'
                          f' .. {np.round(hi, 4).tolist()}), so no ray would reach the field; '
                          'expected field_center/field_scale around the container (python -m '
                          'reneus_mi.scene writes them)')


def load_json(path: str | os.PathLike, what: str = 'file') -> dict:
    """A JSON object from ``path``, or one line naming the file and the fault."""
    path = os.fspath(path)
    try:
        with open(path) as f:
            data = json.load(f)
    except OSError as e:
        raise ReneusError(f'{path}: cannot read the {what} ({e.strerror})') from None
    except ValueError as e:
        raise ReneusError(f'{path}: {what} is not valid JSON ({e})') from None
    if not isinstance(data, dict):
        raise ReneusError(f'{path}: {what}: expected a JSON object')
    return data


#: Bytes per sample slot (ray x segment x sample) of a training step, a floor.
#: Measured peak RSS on the CPU (3 steps, statuette 16x16): a 16-wide field
#: with 8 + 8 samples and 3 segments grew by 4.6 KB per ray from 1024 to 32768
#: rays, i.e. 96 B per slot; a 64-wide, 6-layer field with 32 + 32 samples
#: peaked at 694 MB for 16384 rays (<= 220 B per slot, compilation included).
BYTES_PER_SAMPLE_SLOT = 64


def training_bytes(batch_rays: int, samples_per_segment: int, segments: int) -> int:
    """A floor of the memory of one training step (see :data:`BYTES_PER_SAMPLE_SLOT`).

    A batch above it cannot fit; one below it may still be too large.
    """
    return batch_rays * samples_per_segment * segments * BYTES_PER_SAMPLE_SLOT


def check_keys(given: dict, allowed, where: str) -> None:
    """Refuse keys of ``given`` (a stored configuration) that are not in ``allowed``."""
    unknown = sorted(set(given) - set(allowed))
    if unknown:
        raise ReneusError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; expected "
                          f"some of {', '.join(sorted(allowed))}")


def dataset_fingerprint(ds) -> dict:
    """What identifies a dataset's views: their number, size, names and camera centres.

    Stored with a run, it lets ``--resume --data MOVED`` check that the moved
    folder holds the same photographs and cameras.
    """
    return {'views': len(ds), 'width': ds.width, 'height': ds.height, 'names': list(ds.names),
            'centres': [[round(float(x), 5) for x in c] for c in ds.c2w[:, :3, 3]]}


def check_same_dataset(saved: dict, ds, where: str) -> None:
    """Refuse ``ds`` unless it matches the fingerprint ``saved`` of a run's dataset."""
    now = dataset_fingerprint(ds)
    for key in ('views', 'width', 'height', 'names'):
        if saved.get(key) != now[key]:
            raise ReneusError(f'{where}: dataset {ds.root} differs from the run\'s ({key}: '
                              f'{_short(now[key])}, the run had {_short(saved.get(key))}); '
                              'expected the same photographs')
    import numpy as np
    if not np.allclose(saved['centres'], now['centres'], atol=1e-4):
        raise ReneusError(f"{where}: dataset {ds.root} has other camera positions than the run's; "
                          'expected the same cameras')


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + '...'


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


def read_log(path: str | os.PathLike) -> list[dict]:
    """The entries of a run's ``log.jsonl``; a torn last line (a kill mid-write) is skipped."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        return []
    with open(path) as f:
        lines = [line for line in f.read().split('\n') if line.strip()]
    entries = []
    for n, line in enumerate(lines):
        try:
            entry = json.loads(line)
            int(entry['iteration'])
        except (ValueError, KeyError, TypeError):
            if n == len(lines) - 1:
                break
            raise ReneusError(f'{path}: line {n + 1} is not a log entry ({line[:40]!r}); '
                              "expected JSON with an 'iteration'") from None
        entries.append(entry)
    return entries


def repair_log(path: str | os.PathLike, iteration: int) -> list[dict]:
    """Keep the log lines of steps up to ``iteration`` (a checkpoint's); return them.

    Lines after the checkpoint (a resumed run redoes those steps) and a torn
    last line are dropped. Missing steps before ``iteration`` are reported
    with a warning: the run itself is whole, its record is not.
    """
    import warnings
    from reneus_mi.io import atomic_write_text
    path = os.fspath(path)
    if not os.path.isfile(path):  # a trainer driven by hand keeps no log
        return []
    entries = [e for e in read_log(path) if int(e['iteration']) <= iteration]
    missing = sorted(set(range(1, iteration + 1)) - {int(e['iteration']) for e in entries})
    if missing:
        warnings.warn(f'{path}: no log line for {len(missing)} of the {iteration} steps before the '
                      f'checkpoint (first: {missing[:3]}); the run goes on, its log has gaps')
    atomic_write_text(path, ''.join(json.dumps(e) + '\n' for e in entries))
    return entries


def recent_psnr(entries: list[dict], n: int = 100) -> float | None:
    """Mean PSNR of the last ``n`` log entries, None when there are none."""
    values = [e['psnr'] for e in entries[-n:] if isinstance(e.get('psnr'), (int, float))]
    return sum(values) / len(values) if values else None


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
