"""A collection as one job (issue #19): three tiny specimens with the middle one broken on
each engine, a SIGKILLed worker resumed exactly, two batches on one folder, permissions.

The specimens are copies of the tiny statuette dataset (``tiny.py``), trained with the
``tiny`` preset: seconds each, most of it starting the worker process.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from reneus_mi.batch import engines
from reneus_mi.batch.batch_folder import BatchFolder
from reneus_mi.batch.collection import read_collection
from reneus_mi.batch.dispatch import run_batch
from tiny import assert_same_state, file_state

#: The broken specimen's fault, and the one line its run must end with.
BROKEN = "frames[0]: 'transform_matrix' must be a 4x4 matrix of numbers"


@pytest.fixture(scope='module')
def collection(scene_xml, tmp_path_factory):
    """A folder of three datasets a, b, c; b's first camera is not a matrix."""
    root = tmp_path_factory.mktemp('collection')
    for name in 'abc':
        shutil.copytree(os.path.join(os.path.dirname(scene_xml), 'box'), root / name)
    meta = json.loads((root / 'b' / 'transforms.json').read_text())
    meta['frames'][0]['transform_matrix'][0][0] = 'x'
    (root / 'b' / 'transforms.json').write_text(json.dumps(meta))
    return root


def _engine(name, **options):
    def make(configs, files_of, tasks):
        return engines.make_engine(name, configs, files_of, tasks=tasks, **options)
    return make


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def _ray_engine(tmp_path):
    ray = pytest.importorskip('ray', reason="the ray extra is not installed (pip install -e '.[test]')")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    return _engine('ray', cpus=1), ray.shutdown


def _slurm_engine(tmp_path):
    pytest.importorskip('submitit', reason="the slurm extra is not installed (pip install -e '.[test]')")
    return _engine('slurm', cpus=1, slurm_cluster='local', slurm_folder=str(tmp_path / 'runs' / '_batch' / 'slurm'),
                   ), lambda: None


ENGINES = {'local': lambda tmp_path: (_engine('local', workers=2, threads=1), lambda: None),
           'ray': _ray_engine, 'slurm': _slurm_engine}


@pytest.mark.parametrize('engine', list(ENGINES))
def test_the_broken_specimen_fails_alone(engine, collection, tmp_path, umask_022):
    """On each engine: b fails with its one-line reason, a and c finish with their figures;
    every file is readable by the group; the next batch retries b and leaves a and c."""
    make, close = ENGINES[engine](tmp_path)
    runs = tmp_path / 'runs'
    specimens = read_collection(str(collection), preset='tiny')
    try:
        states = run_batch(specimens, str(runs), make, say=lambda _: None)
    finally:
        close()
    assert states['a'].name == states['c'].name == 'finished'
    assert states['b'].name == 'failed' and BROKEN in states['b'].reason and '\n' not in str(states['b'])
    rows = {r['name']: r for r in _summary(runs)}
    for name in 'ac':
        result = json.loads((runs / name / 'result.json').read_text())
        assert result['iterations'] == 6 and (runs / name / 'mesh.ply').is_file()
        r = rows[name]
        assert (r['state'], int(r['iterations'])) == ('finished', 6)
        assert 5.0 < float(r['psnr']) < 40.0 and float(r['wall_s']) > 0
        # The dataset has a ground truth: a Chamfer distance, the same as one computed here.
        assert float(r['chamfer']) == pytest.approx(_chamfer(runs / name / 'mesh.ply', collection / name), abs=1e-4)
        assert (runs / r['preview']).is_file() and r['mesh'] == f'{name}/mesh.ply'
        # Its package's report page, which summary.html links from the thumbnail.
        assert r['page'] == f'_batch/{name}/package/{name}.html' and (runs / r['page']).is_file()
        assert f'<a href="{r["page"]}"><img src="{r["preview"]}"' in (runs / 'summary.html').read_text()
    assert rows['b']['state'] == 'failed' and BROKEN in rows['b']['reason'] and not rows['b']['page']
    assert 'a/mesh.ply' in (runs / 'summary.html').read_text()
    modes = {os.path.relpath(os.path.join(d, f), runs): os.stat(os.path.join(d, f)).st_mode & 0o777
             for d, _, files in os.walk(runs) for f in files}
    assert {m for p, m in modes.items() if not p.startswith('_batch/slurm')} == {0o644}, modes
    if engine != 'local':
        return
    # Again: b is retried, a and c are not touched.
    stamps = {n: os.path.getmtime(runs / n / 'checkpoint.npz') for n in 'ac'}
    states = run_batch(specimens, str(runs), make, say=lambda _: None)
    assert BROKEN in states['b'].reason and len(BatchFolder(runs).specimen('b').read_attempts()) == 2
    assert {n: os.path.getmtime(runs / n / 'checkpoint.npz') for n in 'ac'} == stamps
    assert [len(BatchFolder(runs).specimen(n).read_attempts()) for n in 'ac'] == [1, 1]
    # Asked to: a starts over, c is left.
    states = run_batch(specimens, str(runs), make, redo=['a'], say=lambda _: None)
    assert states['a'].name == 'finished' and os.path.getmtime(runs / 'c' / 'checkpoint.npz') == stamps['c']
    assert [len(BatchFolder(runs).specimen(n).read_attempts()) for n in 'ac'] == [2, 1]
    assert len((runs / 'a' / 'log.jsonl').read_text().splitlines()) == 6


def _summary(runs):
    import csv
    with open(runs / 'summary.csv') as f:
        return list(csv.DictReader(f))


def _chamfer(mesh, data):
    from reneus_mi.data import load_dataset
    from reneus_mi.geometry.chamfer import chamfer
    from reneus_mi.geometry.mesh import load_mesh
    return chamfer(load_mesh(mesh), load_mesh(load_dataset(str(data)).gt_mesh))['chamfer']


def _manifest(tmp_path, collection, rows) -> str:
    path = tmp_path / 'manifest.json'
    path.write_text(json.dumps([dict(row, data=str(collection / row['data'])) for row in rows]))
    return str(path)


def _batch_process(manifest, runs, *options) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'reneus_mi.batch', manifest, '-o', str(runs), '--preset', 'tiny',
                             '--workers', '1', '--threads', '1', *options],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(test, timeout=120.0, what=''):
    end = time.monotonic() + timeout
    while not test():
        assert time.monotonic() < end, f'timed out waiting for {what}'
        time.sleep(0.01)


#: A run long enough to be caught in the middle, checkpointed every step.
LONG = {'train.iterations': 40, 'train.checkpoint_every': 1}
#: No checkpoint between steps: a Ctrl-C always finds work to keep (deferred to the step's end).
UNSAVED = {'train.checkpoint_every': 1000}


def test_a_killed_worker_is_resumed_exactly(collection, tmp_path):
    """SIGKILL the worker mid-run: the batch records why and when, and the next batch resumes
    the run from its checkpoint to the same state, bit for bit (one thread), as a run never
    killed."""
    manifest = _manifest(tmp_path, collection, [dict(name='a', data='a', **LONG)])
    runs, whole = tmp_path / 'runs', tmp_path / 'whole'
    proc = _batch_process(manifest, runs)
    log = runs / 'a' / 'log.jsonl'
    _wait_for(lambda: log.is_file() and len(log.read_text().splitlines()) >= 5, what='five steps')
    worker = int((runs / 'a' / '.lock').read_text().split()[0])
    os.kill(worker, signal.SIGKILL)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    step = json.loads((runs / 'a' / 'result.json').read_text())['iterations']
    reason = f'worker killed by SIGKILL at step {step}; the next batch resumes it from its checkpoint'
    assert f'a: failed ({reason}' in out and 5 <= step < 40
    before = log.read_text().splitlines()
    proc = _batch_process(manifest, runs)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0 and 'a: finished' in out and out.rstrip().endswith('1 of 1 finished'), (out, err)
    proc = _batch_process(manifest, whole)
    assert proc.communicate(timeout=120) and proc.returncode == 0
    assert_same_state(file_state(whole / 'a' / 'checkpoint.npz'), file_state(runs / 'a' / 'checkpoint.npz'),
                      exact=True)
    after = log.read_text().splitlines()
    assert [json.loads(line)['iteration'] for line in after] == list(range(1, 41))
    # Resumed, not started over: the steps before the checkpoint were not run again (each
    # line holds its step's own timing).
    assert after[:step - 1] == before[:step - 1]
    attempts = BatchFolder(runs).specimen('a').read_attempts()
    assert [a['outcome'] for a in attempts] == ['failed', 'finished'] and attempts[0]['reason'] == reason


#: A line of Ray's own logging (it starts a local Ray with a few of them on stderr).
RAY_LOG = re.compile(r'^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+\s')
#: Each engine's options for one run at a time on one core.
ONE_RUN = {'local': ['--workers', '1', '--threads', '1'], 'ray': ['--engine', 'ray', '--cpus-per-run', '1']}


@pytest.mark.parametrize('engine', list(ONE_RUN))
@pytest.mark.parametrize('to', ['batch', 'group'])
def test_ctrl_c_stops_the_batch_and_its_runs_resumably(collection, tmp_path, to, engine):
    """SIGINT to the batch alone (kill -INT) or to its process group (a terminal's Ctrl-C):
    the batch ends promptly with one line and status 130, its worker writes its checkpoint
    and stops (none is left running), the run is resumable, not failed, and the next batch
    finishes it from there. Harmful before: the batch ended at once and left its worker
    running, holding the run; a worker interrupted with steps not yet checkpointed (the
    usual case: here every step is unsaved) died of the KeyboardInterrupt its run raised after
    writing the checkpoint, and the batch recorded the run failed; and with Ray the batch shut
    Ray down right after cancelling, killing the task before its checkpoint (the run 'new',
    its steps lost, the summary saying 'running')."""
    if engine == 'ray':
        pytest.importorskip('ray', reason="the ray extra is not installed (pip install -e '.[test]')")
    manifest = _manifest(tmp_path, collection, [dict(name='a', data='a', **dict(LONG, **UNSAVED))])
    runs = tmp_path / 'runs'
    proc = subprocess.Popen([sys.executable, '-m', 'reneus_mi.batch', manifest, '-o', str(runs), '--preset', 'tiny',
                             *ONE_RUN[engine]],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    log = runs / 'a' / 'log.jsonl'
    _wait_for(lambda: log.is_file() and len(log.read_text().splitlines()) >= 5, what='five steps')
    worker = int((runs / 'a' / '.lock').read_text().split()[0])
    if to == 'batch':
        proc.send_signal(signal.SIGINT)
    else:
        os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, (out, err)
    assert [line for line in err.strip().splitlines() if not RAY_LOG.match(line)] == [
        'interrupted: each run wrote its checkpoint and stopped; run the same command again to continue'], err
    _wait_for(lambda: not os.path.exists(f'/proc/{worker}') or
              open(f'/proc/{worker}/stat').read().split()[2] == 'Z', timeout=5, what='the worker to end')
    from reneus_mi.train.run_folder import RunFolder
    state = RunFolder(runs / 'a').state()
    assert state.name == 'resumable', state
    assert _summary(runs)[0]['state'] == 'resumable'
    step = len(log.read_text().splitlines())
    assert 5 <= step < 40 and not BatchFolder(runs).specimen('a').read_attempts()
    out, err = _batch_process(manifest, runs).communicate(timeout=120)
    assert 'a: finished' in out, (out, err)
    lines = [json.loads(line) for line in log.read_text().splitlines()]
    assert [e['iteration'] for e in lines] == list(range(1, 41))



def test_a_second_ctrl_c_takes_the_workers_with_the_batch(collection, tmp_path):
    """Ctrl-C twice: the batch ends at once, and its worker with it (killed before its
    checkpoint), and the last line says so. Harmful before: the batch said 'each run wrote
    its checkpoint and stopped' while its worker, in a session of its own, trained on to the
    end, detached."""
    manifest = _manifest(tmp_path, collection, [dict(name='a', data='a', **dict(LONG, **UNSAVED))])
    runs = tmp_path / 'runs'
    proc = _batch_process(manifest, runs)
    log = runs / 'a' / 'log.jsonl'
    _wait_for(lambda: log.is_file() and len(log.read_text().splitlines()) >= 5, what='five steps')
    worker = int((runs / 'a' / '.lock').read_text().split()[0])
    proc.send_signal(signal.SIGINT)
    time.sleep(0.05)             # apart: the kernel merges a signal sent while one is pending
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, (out, err)
    assert err.strip().splitlines() == [
        'interrupted: 1 run(s) killed at the second Ctrl-C, before their checkpoint: each resumes from its last '
        'one; run the same command again to continue'], err
    # Gone with the batch (or a zombie whose parent is gone), not training on.
    assert not os.path.exists(f'/proc/{worker}') or open(f'/proc/{worker}/stat').read().split()[2] == 'Z'
    steps = len(log.read_text().splitlines())
    time.sleep(1.0)
    assert len(log.read_text().splitlines()) == steps < 40
    out, err = _batch_process(manifest, runs).communicate(timeout=120)
    assert 'a: finished' in out, (out, err)

_HOLD = """
import sys, time
from reneus_mi.train.run_folder import RunFolder
with RunFolder(sys.argv[1]).lock():
    print('holding', flush=True)
    time.sleep(600)
"""


def test_two_batches_never_share_a_run(collection, tmp_path):
    """Two batches started together on one folder: one drives it, the other refuses; a run
    another process holds (an optimize by hand) is left alone by both."""
    manifest = _manifest(tmp_path, collection, [dict(name='a', data='a', ior=1.52, **LONG), dict(name='c', data='c')])
    runs = tmp_path / 'runs'
    holder = subprocess.Popen([sys.executable, '-c', _HOLD, str(runs / 'c')], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == 'holding\n'
        first, second = _batch_process(manifest, runs), _batch_process(manifest, runs)
        outs = [p.communicate(timeout=180) for p in (first, second)]
    finally:
        holder.kill()
        holder.wait()
    refused = [err for out, err in outs if 'another batch' in err]
    assert len(refused) == 1, outs
    assert f'{runs}: another batch (process ' in refused[0] and refused[0].count('\n') == 1
    driven = next(out for out, err in outs if 'another batch' not in err)
    assert 'a: finished' in driven and f'c: left alone: process {holder.pid} drives it' in driven
    assert len(BatchFolder(runs).specimen('a').read_attempts()) == 1
    # The manifest's IOR is the scene's.
    assert 'name="int_ior" value="1.52"' in open(BatchFolder(runs).specimen('a').scene).read()
    assert os.listdir(runs / 'c') == ['.lock'] and not os.path.exists(BatchFolder(runs).specimen('c').path)


@pytest.mark.slow
def test_capture_folders(simulated_capture, tmp_path):
    """A capture folder (photographs and capture.json) becomes a dataset in the batch's folder
    and then a run whose mesh is in the board's millimetres, inside the container; a capture
    whose capture.json lacks a setting fails alone, naming it."""
    drawer = tmp_path / 'drawer'
    shutil.copytree(simulated_capture['photos'], drawer / 'moth')
    shutil.copytree(simulated_capture['photos'], drawer / 'wasp')
    settings = json.loads((drawer / 'wasp' / 'capture.json').read_text())
    del settings['size_mm']
    (drawer / 'wasp' / 'capture.json').write_text(json.dumps(settings))
    runs = tmp_path / 'runs'
    states = run_batch(read_collection(str(drawer), preset='tiny'), str(runs), _engine('local', workers=1),
                       say=lambda _: None)
    assert states['moth'].name == 'finished' and 'size_mm is not given' in states['wasp'].reason
    files = BatchFolder(runs).specimen('moth')
    report = json.loads(open(os.path.join(files.dataset, 'report.json')).read())
    assert len(report['views']) == len(simulated_capture['meta']['views'])
    import trimesh
    (x, y, _), (w, d, _) = simulated_capture['meta']['container']['pose'], simulated_capture['meta']['container']['size_mm']
    centre = trimesh.load(runs / 'moth' / 'mesh.ply').bounds.mean(axis=0)
    assert np.hypot(centre[0] - x, centre[1] - y) < 0.5 * min(w, d), centre
    assert os.path.isfile(files.preview)
