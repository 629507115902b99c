"""The batch: every specimen of a collection run by an engine, by the state of its run folder.

:func:`run_batch` holds the batch folder's lock (one batch process per
RUNS_DIR), reads each run's state from disk and

============  ================================================================
state         what the batch does
============  ================================================================
new           starts it
resumable     resumes it from its checkpoint (a killed run)
failed        tries it again: from its checkpoint if it has one, else anew
finished      leaves it, unless ``redo`` names it (then it starts over)
running       leaves it: another process drives it (its lock)
============  ================================================================

It hands the runs to the engine, records a worker's death in its run
(``failed``, with the reason: the next batch resumes it), rewrites the summary
whenever a run ends and prints a progress line. Ctrl-C is passed on to the engine
(:attr:`~reneus_mi.batch.engines.Engine.on_interrupt` says what that does: the local
workers checkpoint and stop); the summary is written and the batch ends with one line.
"""
from __future__ import annotations

import json
import os
import time
from typing import Callable

from reneus_mi.batch import summary
from reneus_mi.batch.batch_folder import RESERVED, BatchFolder
from reneus_mi.batch.collection import Specimen
from reneus_mi.batch.worker import record_death
from reneus_mi.config import with_settings
from reneus_mi.presets import preset
from reneus_mi.train.run_folder import RunState
from reneus_mi.train.run_folder import RunFolder
from reneus_mi.utils import guards, interrupt
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_write_text

#: Seconds between progress lines while nothing ends.
HEARTBEAT = 60.0
#: Seconds between looks at the engine: how long a Ctrl-C waits to be passed on.
TICK = 0.5


def check_folder(root: str, specimens: list[Specimen], collection: str | None = None) -> BatchFolder:
    """RUNS_DIR may hold only what batches write (runs of this or an earlier collection, the
    summaries, the batch's own folder), and lie apart from every specimen's data and from a
    collection folder (whose every subfolder is a specimen)."""
    present = os.listdir(root) if os.path.isdir(root) else []
    runs = [n for n in present if os.path.isfile(RunFolder(os.path.join(root, n)).config)]
    folder = [collection] if collection is not None and os.path.isdir(collection) else []
    guards.check_output_dir(root, inputs=[*folder, *(s.data for s in specimens)],
                            allow=(*RESERVED, *runs, *(s.name for s in specimens)), what='batch folder')
    return BatchFolder(root)


def run_batch(specimens: list[Specimen], root: str, make_engine: Callable, *, redo=(),
              say: Callable[[str], None] = print, collection: str | None = None) -> dict[str, RunState]:
    """Run ``specimens`` (of ``collection``, a folder or a manifest) in ``root/<name>`` on the
    engine ``make_engine(configs, files_of, tasks)`` returns; ``redo``: names (or ``'all'``)
    of runs to start over. Returns each specimen's state when the batch ends."""
    batch = check_folder(root, specimens, collection)
    redo = {s.name for s in specimens} if 'all' in redo else set(redo)
    unknown = sorted(redo - {s.name for s in specimens})
    if unknown:
        raise ReneusError(f"--redo {', '.join(unknown)}: not in the collection; expected names of its specimens")
    os.makedirs(batch.work, exist_ok=True)
    lock = batch.lock()
    try:
        lock.acquire()
    except ReneusError:
        raise ReneusError(f'{batch.path}: another batch ({lock.owner() or "a process"}) drives it; '
                          'expected one batch per folder: wait for it, or choose another -o') from None
    try:
        return _drive(batch, specimens, make_engine, redo, say)
    finally:
        lock.release()


def _drive(batch, specimens, make_engine, redo, say) -> dict[str, str]:
    atomic_write_text(batch.collection, json.dumps([s.to_dict() for s in specimens], indent=2))
    counts = {'finished': 0, 'failed': 0, 'running': 0, 'left': 0, 'busy': 0}
    todo = []
    for s in specimens:
        state = batch.run(s.name).state()
        if state.name == 'finished' and s.name not in redo:
            counts['finished'] += 1
        elif state.name == 'running':
            counts['busy'] += 1
            say(f'{s.name}: left alone: {state.reason} drives it')
        else:
            todo.append(s)
    counts['left'] = len(todo)
    summary.write(batch, specimens)
    if not todo:
        say(summary.progress_line(counts, time.monotonic(), 0))
        return _states(batch, specimens)
    configs = [with_settings(preset(s.preset), s.settings)[0] for s in todo]
    engine = make_engine(configs, batch.specimen, len(todo))
    say(f'{len(todo)} run(s) on {engine.describe()}; summary in {batch.summary_html}')
    started, ended = time.monotonic(), 0
    tasks = [{'specimen': s.to_dict(), 'root': batch.path, 'threads': engine.threads,
              'variant': engine.variant, 'redo': s.name in redo, 'engine': engine.name} for s in todo]

    def settle(done):
        nonlocal ended
        for task, outcome in done:
            name = task['specimen']['name']
            counts['running'] -= 1
            state = _settle(batch, name, outcome, engine.name)
            counts[state.name if state.name in ('finished', 'failed') else
                   'busy' if state.name == 'running' else 'left'] += 1
            ended += 1
            say(f'{name}: {state}')
        if done:
            summary.write(batch, specimens)

    # A second Ctrl-C ends the batch at once: the engine ends what is out with it (the line is
    # made then, so that it says what was done).
    interrupt.leaving(lambda: f'{engine.abandon() or engine.on_interrupt}; run the same command again to continue')
    # While runs are out, Ctrl-C is the engine's to pass on (the runs' checkpoints); with
    # none out it ends the batch at once.
    with interrupt.deferred(unsaved=engine.running) as interrupted:
        heard = time.monotonic()
        while (tasks or engine.running()) and not interrupted():
            free = engine.free()
            taken, tasks = tasks[:free], tasks[free:]
            engine.submit(taken)
            counts['left'] -= len(taken)
            counts['running'] += len(taken)
            done = engine.wait(TICK)
            settle(done)
            if taken or done or time.monotonic() - heard >= HEARTBEAT:
                say(summary.progress_line(counts, started, ended))
                heard = time.monotonic()
        settle(engine.close())
        if interrupted():
            raise KeyboardInterrupt
    return _states(batch, specimens)


def _settle(batch, name: str, outcome: dict, engine: str):
    """The run's state once its task ended: a dead worker's run is recorded failed."""
    folder = batch.run(name)
    if outcome.get('outcome') == 'died':
        log = folder.read_log() if os.path.isfile(folder.log) else []
        step = f" at step {log[-1]['iteration']}" if log else ''
        resume = ('; the next batch resumes it from its checkpoint' if os.path.isfile(folder.checkpoint)
                  else '; the next batch starts it again')
        record_death(folder, batch.specimen(name), f"{outcome['reason']}{step}{resume}",
                     outcome.get('seconds'), engine)
    return folder.state()


def _states(batch, specimens) -> dict[str, RunState]:
    return {s.name: batch.run(s.name).state() for s in specimens}
