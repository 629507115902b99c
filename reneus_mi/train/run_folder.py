"""A run's folder: the one place that knows its files, its lock, its log, its result and its state.

A reconstruction lives in one folder::

    config.json             the whole configuration and where the scene and data came from
    scene_copy/             the scene and the files it names, as the run started: it resumes
                            from them wherever the scene or the data moved since
    log.jsonl               one line every log_every steps: losses by name, PSNR, learning
                            rate, s, rays/s, and the refined IOR, pose and light
    checkpoint.npz          the latest checkpoint (atomic; --resume continues from it)
    images/                 validation renders (image | photograph) and normal maps
    meshes/                 mesh snapshots (64^3) at validation steps
    mesh.ply                the final mesh, in the dataset's world coordinates (a capture's:
                            millimetres in the board's frame; result.json says which)
    mesh.glb                the same for web viewers: vertex colours, metres, y up
    container_refined.ply   the container at its refined pose (train.refine.pose)
    result.json             what the run reports when it ends (or why it failed)
    .lock                   the process that drives the run (a kernel lock: :class:`RunLock`)

:meth:`RunFolder.state` reads from disk, in any process, what the folder holds:
``new`` (nothing to continue: empty, or an attempt killed before its first
checkpoint, which a new run replaces), ``running`` (a live process holds its lock),
``resumable`` (a checkpoint and no result: a killed run), ``finished`` or
``failed`` (a result, with the reason; a run that failed before its first
checkpoint leaves nothing to continue, and a new run replaces it). Every command
reads it the same way (:meth:`RunFolder.check_start`) and names it in its
messages (:meth:`RunState.advice`); that is also what a batch of runs needs to
skip, continue or report each one.
"""
from __future__ import annotations

import json
import os
import shutil
import socket
import time
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import fcntl

from reneus_mi.train.checkpoint import load_meta
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_folder, atomic_write_text, is_temporary, load_json

#: The states of a run folder, as :meth:`RunFolder.state` names them.
STATES = ('new', 'running', 'resumable', 'finished', 'failed')


@dataclass(frozen=True)
class RunState:
    """What a run folder holds: one of :data:`STATES`, why (a failure, the lock's owner), and
    its checkpoint (whether there is one, and its step when it can be read)."""
    name: str
    reason: str = ''
    checkpoint: bool = False
    step: int | None = None

    def __str__(self) -> str:
        details = [self.reason] if self.reason else []
        if self.checkpoint:
            details.append('no readable checkpoint' if self.step is None else f'checkpoint of step {self.step}')
        return f"{self.name} ({'; '.join(details)})" if details else self.name

    @property
    def takes_new_run(self) -> bool:
        """Whether a new run may start in the folder: it holds nothing to continue."""
        return self.name == 'new' or (self.name == 'failed' and not self.checkpoint)

    @property
    def takes_resume(self) -> bool:
        """Whether ``--resume`` continues something: a checkpoint no process is driving."""
        return self.name != 'running' and self.checkpoint

    def advice(self) -> str:
        """What the folder takes next, in the options' words."""
        if self.name == 'running':
            return f'wait for {self.reason} to end'
        if self.takes_new_run:
            return 'nothing to continue: a new run (without --resume) starts in it'
        if self.name == 'finished':
            return 'it is finished: --resume with more --iterations continues it'
        if self.name == 'failed':
            return 'continue it from its checkpoint with --resume, after changing what failed'
        return 'continue it with --resume'


class FolderFile:
    """A file of a folder object (one with a ``path``): its name on the class
    (``RunFolder.log``), its path on an instance. ``names`` are the parts of a path inside
    the folder."""

    def __init__(self, *names: str):
        self.name = os.path.join(*names)

    def __get__(self, folder, owner=None) -> str:
        return self.name if folder is None else os.path.join(folder.path, self.name)


@dataclass(frozen=True)
class RunFolder:
    """The folder of one run and the names of what it holds."""

    path: str

    config = FolderFile('config.json')
    scene_copy = FolderFile('scene_copy')
    log = FolderFile('log.jsonl')
    checkpoint = FolderFile('checkpoint.npz')
    images = FolderFile('images')
    meshes = FolderFile('meshes')
    mesh = FolderFile('mesh.ply')
    web_mesh = FolderFile('mesh.glb')
    container = FolderFile('container_refined.ply')
    result = FolderFile('result.json')
    lock_file = FolderFile('.lock')

    def __post_init__(self):
        object.__setattr__(self, 'path', os.fspath(self.path))

    # ------------------------------------------------------------- checks
    def check(self, *, inputs=(), resume: bool = False) -> str:
        """Check the folder before a run writes into it; return its absolute path.

        Apart from the inputs and any dataset folder
        (:func:`~reneus_mi.utils.guards.check_output_dir`); a new run needs a new or
        empty folder, or one holding only what a run writes without its
        checkpoint (a run killed before its first one, which starts over);
        ``resume`` accepts whatever the run folder holds.
        """
        present = os.listdir(self.path) if os.path.isdir(self.path) else []
        allow = present if resume else [n for n in present
                                        if (n in FILES and n != RunFolder.checkpoint) or is_temporary(n)]
        return guards.check_output_dir(self.path, inputs=inputs, allow=allow, what='output folder')

    def lock(self) -> 'RunLock':
        """The folder's lock (a context manager): one process drives a run."""
        return RunLock(self.lock_file)

    def remove_stray_temporaries(self) -> list[str]:
        """Delete the temporaries (files, folders) an atomic write left behind when it was killed."""
        removed = []
        if os.path.isdir(self.path):
            for name in os.listdir(self.path):
                if is_temporary(name):
                    path = os.path.join(self.path, name)
                    shutil.rmtree(path) if os.path.isdir(path) else os.unlink(path)
                    removed.append(name)
        return removed

    def keep_scene(self, path: str) -> str:
        """Copy the scene XML ``path`` and every file it names (its ``filename`` properties:
        container meshes, textures) into :attr:`scene_copy`, the references rewritten to the
        copies; return the copy's XML.

        A run keeps such a copy and resumes from it (:meth:`scene_to_load`), so the scene file,
        the container files beside it and the dataset holding them may all move after the run
        started (``--resume --data MOVED``). A reference that Mitsuba resolves only when loading
        (``$name``, a file on its search path) is kept as written; the integrator's ``dataset``
        is made absolute.
        """
        base = os.path.dirname(os.path.abspath(path))
        try:
            tree = ET.parse(path)
        except (OSError, ET.ParseError) as e:
            raise ReneusError(f'{path}: cannot read the scene ({e})') from None
        with atomic_folder(self.scene_copy) as work:
            copies: dict[str, str] = {}
            for element in tree.iter('string'):
                name, value = element.get('name'), element.get('value', '')
                if name not in ('filename', 'dataset') or '$' in value or not value:
                    continue
                source = os.path.abspath(os.path.join(base, value))
                if name == 'dataset':
                    element.set('value', source)
                elif os.path.isfile(source):
                    if source not in copies:
                        copies[source] = f'{len(copies)}_{os.path.basename(source)}'
                        shutil.copyfile(source, os.path.join(work, copies[source]))
                    element.set('value', copies[source])
            with open(os.path.join(work, 'scene.xml'), 'wb') as f:
                tree.write(f, encoding='utf-8', xml_declaration=True)
        return os.path.join(self.scene_copy, 'scene.xml')

    def scene_to_load(self, recorded: str) -> str:
        """The scene a continued run loads: its own copy (the run's scene as it started), else
        the ``recorded`` file (a folder from before copies were kept)."""
        copy = os.path.join(self.scene_copy, 'scene.xml')
        return copy if os.path.isfile(copy) else recorded

    # -------------------------------------------------------------- state
    def state(self) -> RunState:
        """What the folder holds, read from disk (see the module docstring)."""
        if not os.path.isdir(self.path):
            return RunState('new')
        owner = self.lock().owner()
        if owner is not None:
            return RunState('running', owner)
        return self.recorded_state()

    def recorded_state(self) -> RunState:
        """The state its files record, whoever holds the lock (a process saying what its own
        run leaves)."""
        checkpoint = os.path.isfile(self.checkpoint)
        step = self.checkpoint_step() if checkpoint else None
        result = self.read_result() if os.path.isdir(self.path) else None
        if result is not None:
            failure = result.get('failure')
            return RunState('failed' if failure else 'finished', str(failure or ''), checkpoint, step)
        return RunState('resumable' if checkpoint else 'new', '', checkpoint, step)

    def checkpoint_step(self) -> int | None:
        """The step of the folder's checkpoint, None when it has none that can be read."""
        try:
            return int(load_meta(self.checkpoint)['iteration'])
        except (ReneusError, KeyError, TypeError, ValueError):
            return None

    def check_start(self, resume: bool = False) -> RunState:
        """Refuse, in one line naming the state and what it takes, a new run (or with
        ``resume`` a continued one) that the folder's state does not take; return the state."""
        # A process that holds the lock (a batch worker preparing its specimen) starts the run
        # it holds: what the files record decides.
        state = self.recorded_state() if self.lock().held_here() else self.state()
        if state.name == 'running':
            raise ReneusError(f'{self.path}: run is in use by {state.reason}; expected one process '
                              'per run folder')
        if resume and not state.takes_resume:
            raise ReneusError(f'{self.path}: nothing to resume ({state}); {state.advice()}')
        if not resume and not state.takes_new_run:
            raise ReneusError(f'{self.path} already holds a run ({state}); {state.advice()}, or choose '
                              'another output folder')
        return state

    # ----------------------------------------------------- config, result
    def read_config(self) -> dict:
        """The run's recorded configuration (``config.json``)."""
        if not os.path.exists(self.config):
            raise ReneusError(f'{self.path}: nothing to resume (no {RunFolder.config})')
        return load_json(self.config, "run's configuration")

    def write_config(self, values: dict) -> None:
        atomic_write_text(self.config, json.dumps(values, indent=2))

    def read_result(self) -> dict | None:
        """The run's result, None while it has none (new, running, killed)."""
        return load_json(self.result, "run's result") if os.path.exists(self.result) else None

    def write_result(self, result: dict) -> None:
        atomic_write_text(self.result, json.dumps(result, indent=2))

    def clear_result(self) -> None:
        """Forget an earlier result: a run that goes on is not finished until it ends again."""
        if os.path.isfile(self.result):
            os.unlink(self.result)

    # ---------------------------------------------------------------- log
    def read_log(self) -> list[dict]:
        """The entries of ``log.jsonl``; a torn last line (a kill mid-write) is skipped."""
        if not os.path.isfile(self.log):
            return []
        with open(self.log) as f:
            lines = [line for line in f.read().split('\n') if line.strip()]
        entries = []
        for n, line in enumerate(lines):
            try:
                entry = json.loads(line)
                int(entry['iteration'])
            except (ValueError, KeyError, TypeError):
                if n == len(lines) - 1:
                    break
                raise ReneusError(f'{self.log}: line {n + 1} is not a log entry ({line[:40]!r}); '
                                  "expected JSON with an 'iteration'") from None
            entries.append(entry)
        return entries

    def repair_log(self, iteration: int) -> list[dict]:
        """Keep the log lines of steps up to ``iteration`` (a checkpoint's); return them.

        Lines after the checkpoint (a resumed run redoes those steps) and a torn
        last line are dropped. Missing steps before ``iteration`` are reported
        with a warning: the run itself is whole, its record is not.
        """
        if not os.path.isfile(self.log):  # a trainer driven by hand keeps no log
            return []
        entries = [e for e in self.read_log() if int(e['iteration']) <= iteration]
        missing = sorted(set(range(1, iteration + 1)) - {int(e['iteration']) for e in entries})
        if missing:
            warnings.warn(f'{self.log}: no log line for {len(missing)} of the {iteration} steps before '
                          f'the checkpoint (first: {missing[:3]}); the run goes on, its log has gaps')
        atomic_write_text(self.log, ''.join(json.dumps(e) + '\n' for e in entries))
        return entries


#: Every name a run writes into its folder.
FILES = tuple(f.name for f in vars(RunFolder).values() if isinstance(f, FolderFile))


def recent_psnr(entries: list[dict], n: int = 100) -> float | None:
    """Mean PSNR of the last ``n`` log entries, None when there are none."""
    values = [e['psnr'] for e in entries[-n:] if isinstance(e.get('psnr'), (int, float))]
    return sum(values) / len(values) if values else None


class RunLock:
    """An exclusive lock on a run folder, so that two processes never drive one run.

    The kernel's lock (``flock``) on the lock file: of two processes that ask at
    the same instant only one gets it, and the kernel drops the lock of a
    process that dies (a kill; a lost node once its file server notices), so a
    lock never outlives its owner. The file holds the owner's process id and
    host for the messages; it is removed on release while still locked, and a
    process that locked a file no longer at the path (removed meanwhile) tries
    again. A process that holds the lock may take it again (nested), e.g. a
    batch worker that holds it while it prepares a specimen and then runs it.
    Use as a context manager.
    """

    #: How long :meth:`acquire` retries a lock held by someone else: a look at the
    #: lock (:meth:`owner`, :meth:`RunFolder.state`) holds it for microseconds.
    GRACE = 0.5
    #: The locks this process holds: path -> [file descriptor, depth].
    _held: dict = {}

    def __init__(self, path: str | os.PathLike, what: str = 'run'):
        self.path = os.path.abspath(os.fspath(path))
        self.what = what
        self.held = False

    def acquire(self, wait: float | None = None) -> None:
        """Take the lock, retrying for ``wait`` seconds (default :data:`GRACE`) while
        another process holds it; then refuse in one line naming the holder."""
        if self.held:
            return
        mine = RunLock._held.get(self.path)
        if mine is not None:
            mine[1] += 1
            self.held = True
            return
        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        deadline = time.monotonic() + (self.GRACE if wait is None else wait)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                if time.monotonic() < deadline:
                    time.sleep(0.02)
                    continue
                raise ReneusError(f'{os.path.dirname(self.path)}: {self.what} is in use by '
                                  f'{self.owner() or "another process"}; expected one process per '
                                  f'{self.what} folder') from None
            if _same_file(fd, self.path):
                break
            os.close(fd)   # the holder removed this file as it let go: lock the one at the path
        os.ftruncate(fd, 0)
        os.write(fd, f'{os.getpid()} {socket.gethostname()}\n'.encode())
        RunLock._held[self.path] = [fd, 1]
        self.held = True

    def held_here(self) -> bool:
        """Whether this process holds the lock."""
        return self.path in RunLock._held

    def owner(self) -> str | None:
        """Who holds the lock ('process N', on another host 'process N on HOST'); None when
        nobody does."""
        if self.held_here():
            return f'process {os.getpid()}'
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except FileNotFoundError:
            return None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                text = os.read(fd, 256).decode(errors='replace').split()
                pid = text[0] if text else '?'
                here = len(text) < 2 or text[1] == socket.gethostname()
                return f'process {pid}' + ('' if here else f' on {text[1]}')
            fcntl.flock(fd, fcntl.LOCK_UN)
            return None
        finally:
            os.close(fd)

    def release(self) -> None:
        if not self.held:
            return
        self.held = False
        mine = RunLock._held[self.path]
        mine[1] -= 1
        if mine[1]:
            return
        del RunLock._held[self.path]
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            pass
        os.close(mine[0])

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()


def _same_file(fd: int, path: str) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except FileNotFoundError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


# A forked child holds none of its parent's locks (the kernel's lock stays the parent's).
os.register_at_fork(after_in_child=RunLock._held.clear)
