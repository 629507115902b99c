"""One specimen's run, wherever an engine places it: :func:`run_task`.

Every engine (the local pool, Ray, Slurm) calls the same function with the same
task (a dict: the specimen, the batch folder, the threads, the variant); the run
itself is :func:`reneus_mi.runs.prepare`'s. The worker takes the run's lock
first and holds it throughout: a run held by another process is left alone
(``busy``). Under the lock it

1. prepares the specimen (a capture becomes a dataset; the scene XML is written),
2. runs it: from nothing, or from its checkpoint (a killed or failed run),
3. measures it (Chamfer to the ground truth, where the dataset has one) and
   renders a preview of its mesh.

Whatever goes wrong with one specimen (bad data, a diverging run, an error of
Mitsuba) is written to its ``result.json`` as a one-line failure, and the
worker returns normally: the batch goes on. Only the death of the worker
(SIGKILL, a lost node) leaves the run without a result; the batch process
then records that (:func:`record_death`).
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import socket
import time
import traceback

import drjit as dr
import trimesh

from reneus_mi.batch.collection import Specimen
from reneus_mi.utils.errors import ReneusError, exit_on_error, one_line, user_message
from reneus_mi.utils.io import atomic_write_text
from reneus_mi.utils.variant import set_variant

#: The local worker's exit status when the run is held by another process.
EXIT_BUSY = 75
#: The batch command's option that makes its process a worker of the local pool.
TASK_OPTION = '--task'


def run_task(task: dict) -> dict:
    """Run one specimen (see the module docstring); returns ``{'name', 'outcome', 'reason',
    'seconds'}``, the outcome one of finished, failed, busy (another process holds the run)
    and skipped (finished before)."""
    set_variant(task['variant'])
    # Imported once the task's variant is set, as every import below that reaches the
    # integrator (it is registered per variant).
    from reneus_mi.batch.batch_folder import BatchFolder
    if task.get('threads'):
        dr.set_thread_count(int(task['threads']))
    specimen = Specimen.from_dict(task['specimen'])
    batch = BatchFolder(task['root'])
    folder, files = batch.run(specimen.name), batch.specimen(specimen.name)
    start, started = time.perf_counter(), time.time()
    lock = folder.lock()
    try:
        lock.acquire()
    except ReneusError as e:
        return {'name': specimen.name, 'outcome': 'busy', 'reason': str(e), 'seconds': 0.0}
    try:
        outcome, reason = _attempt(specimen, folder, files, bool(task.get('redo')))
        seconds = time.perf_counter() - start
        if outcome != 'skipped':
            files.add_attempt({'start': started, 'seconds': round(seconds, 3), 'outcome': outcome,
                               'reason': reason, 'engine': task.get('engine', ''),
                               'host': socket.gethostname(), 'pid': os.getpid()})
    finally:
        lock.release()
    return {'name': specimen.name, 'outcome': outcome, 'reason': reason, 'seconds': seconds}


def _attempt(specimen, folder, files, redo: bool) -> tuple[str, str]:
    result = folder.read_result()
    if result is not None and 'failure' not in result and not redo:
        return 'skipped', 'finished before'
    if redo:
        _clear(folder)
    for stale in (files.preview, files.metrics):   # they describe the mesh this attempt replaces
        if os.path.isfile(stale):
            os.unlink(stale)
    shutil.rmtree(files.package, ignore_errors=True)
    try:
        run = specimen_run(specimen, files, folder)
        result = run.train(progress=False)
    except (ReneusError, RuntimeError, OSError) as e:
        # Bad data, an error of Mitsuba's, a full disk: this specimen's, not the batch's.
        return 'failed', _record_failure(folder, one_line(user_message(e) if isinstance(e, RuntimeError)
                                                          else str(e)))
    except Exception as e:  # noqa: BLE001 (a fault of ours must not stop the other specimens)
        traceback.print_exc()
        return 'failed', _record_failure(folder, f'internal error: {type(e).__name__}: {one_line(str(e))}')
    if 'failure' in result:
        return 'failed', result['failure']
    measure(run.dataset, result['mesh'], files)
    publish(specimen, folder, files)
    return 'finished', ''


def specimen_run(specimen, files, folder):
    """The specimen's :class:`~reneus_mi.runs.Run`: a capture captured into
    ``files.dataset`` (once), the scene XML written, the preset and settings applied; from its
    checkpoint where the folder holds one."""
    # Imported here, after run_task set the task's variant (see there).
    from reneus_mi.capture import pipeline, settings as capture_settings
    from reneus_mi.data import load_dataset
    from reneus_mi.data.scene_xml import write_scene
    from reneus_mi import runs
    os.makedirs(files.path, exist_ok=True)
    data = specimen.data
    if specimen.kind == 'capture':
        data = files.dataset
        if not os.path.isfile(os.path.join(data, 'transforms.json')):
            given = dict(specimen.capture, **({'ior': specimen.ior} if specimen.ior is not None else {}))
            pipeline.run(capture_settings.resolve(given, specimen.data), specimen.data, data)
    elif not os.path.isdir(data):
        raise ReneusError(f'{data}: dataset folder does not exist')
    ds = load_dataset(data, need_container=False)
    if specimen.ior is not None and specimen.kind == 'dataset':
        ds = dataclasses.replace(ds, ior=specimen.ior)
    write_scene(ds, files.scene, preset=specimen.preset, overwrite=True)
    return runs.prepare(folder.path, files.scene, data, settings=specimen.settings, start='continue',
                        remedy=f'--redo {specimen.name} to start it over')


def measure(ds, mesh_path: str, files) -> dict:
    """Chamfer to the ground truth of the dataset ``ds`` (if it has one) and a preview of the
    mesh, into ``files.metrics`` and ``files.preview``; an empty mesh has neither."""
    # Imported here, after run_task set the task's variant (see there).
    from reneus_mi.geometry.chamfer import chamfer
    from reneus_mi.geometry.mesh import load_mesh
    from reneus_mi.render.preview import render_preview
    metrics = {}
    mesh = trimesh.load(mesh_path, process=False, force='mesh')
    if len(mesh.faces):
        if ds.gt_mesh:
            metrics['chamfer'] = chamfer(load_mesh(mesh_path), load_mesh(ds.gt_mesh))['chamfer']
        # Seen from the first camera, upright as in its photograph (OpenCV: y points down).
        c2w = ds.c2w[0]
        render_preview(mesh_path, files.preview, direction=c2w[:3, 3] - mesh.bounds.mean(axis=0),
                       up=-c2w[:3, 1])
    atomic_write_text(files.metrics, json.dumps(metrics, indent=2))
    return metrics


def publish(specimen, folder, files) -> None:
    """The finished specimen's package with its report page (:mod:`reneus_mi.export.package`),
    which the summary links. A package that cannot be made is said in the worker's log; the
    run stands."""
    # Imported here, after run_task set the task's variant (see there).
    from reneus_mi.export.package import export_run
    try:
        export_run(folder.path, files.package, identifiers=specimen.identifiers)
    except (ReneusError, RuntimeError, OSError) as e:
        print(f'warning: {specimen.name}: no package ({one_line(str(e))})', flush=True)


def record_death(folder, files, reason: str, seconds: float | None, engine: str) -> bool:
    """Record that the worker of ``folder``'s run died (``reason``), unless another process
    drives the run by now; returns whether it was recorded."""
    lock = folder.lock()
    try:
        lock.acquire()
    except ReneusError:
        return False
    try:
        if folder.read_result() is not None:   # it ended after all (the death came later)
            return False
        _record_failure(folder, reason)
        files.add_attempt({'start': time.time() - (seconds or 0.0), 'seconds': seconds, 'outcome': 'failed',
                           'reason': reason, 'engine': engine, 'host': socket.gethostname(), 'pid': None})
        return True
    finally:
        lock.release()


def _record_failure(folder, reason: str) -> str:
    os.makedirs(folder.path, exist_ok=True)
    previous = folder.read_result() or {}
    folder.write_result({'failure': reason, 'iterations': previous.get('iterations', _iterations(folder))})
    return reason


def _iterations(folder) -> int:
    """The steps the run's checkpoint holds (0 without one), from its log."""
    entries = folder.read_log() if os.path.isfile(folder.checkpoint) else []
    return int(entries[-1]['iteration']) if entries else 0


def _clear(folder) -> None:
    """Start a run over: remove what a run wrote into its folder (asked for with --redo)."""
    # Imported here, after run_task set the task's variant (see there).
    from reneus_mi.train.run_folder import FILES, RunFolder
    for name in FILES:
        path = os.path.join(folder.path, name)
        if name == RunFolder.lock_file:
            continue
        if os.path.isdir(path):
            shutil.rmtree(path)
        elif os.path.exists(path):
            os.unlink(path)
    folder.remove_stray_temporaries()


def work(task_json: str) -> int:
    """A worker process of the local pool (``python -m reneus_mi.batch`` with
    :data:`TASK_OPTION`): run the task, print its outcome as JSON; the exit status says busy."""
    # A run stopped by Ctrl-C with steps to keep writes its checkpoint and raises
    # KeyboardInterrupt: the worker ends with the interrupt's status, which the pool reads as
    # interrupted (resumable), not as a worker killed by the signal.
    with exit_on_error():
        outcome = run_task(json.loads(task_json))
    print(json.dumps(outcome), flush=True)
    return EXIT_BUSY if outcome['outcome'] == 'busy' else 0
