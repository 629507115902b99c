"""Ctrl-C in a command: one line, at once, whatever the command is doing.

Python raises ``KeyboardInterrupt`` only when the main thread next runs Python code, which
may be minutes away while Dr.Jit compiles or launches a kernel, and one raised inside
Mitsuba's callbacks comes back wrapped, or not at all. A command's process therefore takes
SIGINT itself (:func:`install`, run when ``reneus_mi`` is imported by a command, before
Mitsuba loads): a watchdog thread, woken through the signal's wakeup file descriptor even
while the main thread is inside a kernel, removes the files and folders that writes in
flight registered (:func:`temporary`: every atomic write does), prints ``interrupted: ...``
(what the command leaves, as it last said with :func:`leaving`) and ends the process with
status 130. Every write of the package is atomic, so what is left are whole files.

A loop that wants its latest step kept (training) takes the interrupt as a flag instead,
read between steps, for as long as it holds work a checkpoint would keep (:func:`deferred`);
a second Ctrl-C ends the process at once.

Outside a command (a notebook, a test calling a ``main()``) nothing is installed:
``KeyboardInterrupt`` is raised as usual, :func:`temporary` removes its path on the way out,
and :func:`deferred` sets its flag from a Python signal handler. This module imports nothing
but the standard library: it must be ready before the heavy imports start.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
import threading

#: Exit status of a command ended by Ctrl-C (the shell's 128 + SIGINT).
STATUS = 130
#: What an interrupted command leaves when it has said nothing more precise.
NOTHING_HALF_WRITTEN = 'no file is left half-written'

_lock = threading.RLock()
_temporaries: dict[str, None] = {}
_leaving = [NOTHING_HALF_WRITTEN]
_deferral: list = []
_installed = []


def is_command(argv=None) -> bool:
    """Whether this process is one of the package's commands (``python -m reneus_mi.X`` or a
    ``reneus-X`` console script), from the interpreter's own command line."""
    argv = list(getattr(sys, 'orig_argv', sys.argv) if argv is None else argv)
    if '-m' in argv[1:-1]:
        return argv[argv.index('-m', 1) + 1].split('.')[0] == 'reneus_mi'
    return len(argv) > 1 and os.path.basename(argv[1]).startswith('reneus-')


def install() -> None:
    """Take SIGINT in a watchdog thread from now on (a command's process; main thread only)."""
    if _installed or threading.current_thread() is not threading.main_thread():
        return
    read, write = os.pipe()
    os.set_blocking(write, False)
    signal.set_wakeup_fd(write, warn_on_full_buffer=False)
    # Python writes the wakeup byte only for a signal with a Python handler: one that does
    # nothing, so that no KeyboardInterrupt is ever raised inside the main thread's work.
    signal.signal(signal.SIGINT, lambda *_: None)
    threading.Thread(target=_watch, args=(read,), name='reneus-mi interrupt', daemon=True).start()
    _installed.append(True)


def leaving(what) -> None:
    """Say what an interrupt now leaves: a text, or a function that returns it then."""
    _leaving[0] = what


def message() -> str:
    """The line an interrupted command prints."""
    what = _leaving[0]
    try:
        text = what() if callable(what) else what
    except Exception:  # a report must never fail: the files are whole either way
        text = NOTHING_HALF_WRITTEN
    return f'interrupted: {text}'


@contextlib.contextmanager
def temporary(path: str):
    """``path`` (a file or folder being written) is removed if the command is interrupted or
    the block fails; the block keeps it by renaming it into place. Yields ``path``."""
    with _lock:
        _temporaries[path] = None
    try:
        yield path
    except BaseException:
        _remove(path)
        raise
    finally:
        with _lock:
            _temporaries.pop(path, None)


@contextlib.contextmanager
def deferred(unsaved=lambda: True):
    """Within the block Ctrl-C is a flag: the yielded function says whether one came, and the
    loop ends between two steps. In a command this holds while ``unsaved()`` says there is
    work to keep; before that, and at a second Ctrl-C, the command ends at once."""
    if _installed:
        state = {'requested': False, 'unsaved': unsaved}
        with _lock:
            _deferral.append(state)
        try:
            yield lambda: state['requested']
        finally:
            with _lock:
                _deferral.remove(state)
        return
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    flag = []
    previous = signal.signal(signal.SIGINT, lambda *_: flag.append(True))
    try:
        yield lambda: bool(flag)
    finally:
        signal.signal(signal.SIGINT, previous)


def _watch(fd: int) -> None:
    while True:
        try:
            received = os.read(fd, 64)
        except OSError:
            return
        for _ in range(received.count(signal.SIGINT)):
            with _lock:
                state = _deferral[-1] if _deferral else None
                if state is not None and not state['requested'] and _call(state['unsaved']):
                    state['requested'] = True
                    continue
            _end()


def _call(function) -> bool:
    try:
        return bool(function())
    except Exception:
        return False


def _end() -> None:
    """Remove the writes in flight, say what is left, end the process."""
    with _lock:
        for path in reversed(list(_temporaries)):
            _remove(path)
        line = message()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os.write(2, ('\n' if sys.stderr.isatty() else '').encode() + line.encode() + b'\n')
    os._exit(STATUS)


def _remove(path: str) -> None:
    """Delete a temporary file or folder; a folder is first renamed away, so that nothing
    the main thread still writes can land in it."""
    with contextlib.suppress(OSError):
        if os.path.isdir(path) and not os.path.islink(path):
            gone = f'{path}.removed-{os.getpid()}'
            os.rename(path, gone)
            shutil.rmtree(gone, ignore_errors=True)
        else:
            os.unlink(path)
