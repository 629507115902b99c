"""The run folder: its checks, its lock, its log, its state read from disk."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from reneus_mi.errors import ReneusError
from reneus_mi.io import atomic_path, atomic_write_text
from reneus_mi.train.run_folder import RunFolder, recent_psnr


def test_run_dir(tmp_path):
    run = tmp_path / 'run'
    run.mkdir()
    for name in ('config.json', 'log.jsonl', '.tmp-x.npz'):
        (run / name).write_text('')
    RunFolder(run).check()            # a run killed before its first checkpoint
    (run / 'checkpoint.npz').write_text('')
    with pytest.raises(ReneusError, match='holds checkpoint.npz'):
        RunFolder(run).check()
    (run / 'notes.txt').write_text('')
    RunFolder(run).check(resume=True)


def test_run_lock(tmp_path):
    with RunFolder(tmp_path).lock():
        assert (tmp_path / '.lock').read_text() == str(os.getpid())
        with pytest.raises(ReneusError, match=f'in use by process {os.getpid()}'):
            RunFolder(tmp_path).lock().acquire()
    assert not (tmp_path / '.lock').exists()
    # A lock left by a killed process is taken over.
    dead = subprocess.run([sys.executable, '-c', 'import os; print(os.getpid())'],
                          capture_output=True, text=True).stdout.strip()
    (tmp_path / '.lock').write_text(dead)
    with RunFolder(tmp_path).lock():
        assert (tmp_path / '.lock').read_text() == str(os.getpid())


def _checkpoint(folder, step):
    np.savez(folder.checkpoint, meta=np.array(json.dumps({'iteration': step})))


def test_run_state_is_read_from_disk(tmp_path):
    folder = RunFolder(tmp_path / 'run')
    assert folder.state().name == 'new'
    os.makedirs(folder.path)
    (tmp_path / 'run' / 'config.json').write_text('{}')
    assert folder.state().name == 'new'                  # killed before its first checkpoint
    (tmp_path / 'run' / 'checkpoint.npz').write_text('')
    assert str(folder.state()) == 'resumable (no readable checkpoint)'
    _checkpoint(folder, 40)
    assert str(folder.state()) == 'resumable (checkpoint of step 40)'
    with folder.lock():
        assert str(folder.state()) == f'running (process {os.getpid()})'
        assert folder.recorded_state().name == 'resumable'     # what the holder itself leaves
    folder.write_result({'iterations': 3})
    assert folder.state().name == 'finished' and folder.read_result() == {'iterations': 3}
    folder.write_result({'failure': 'step 2: the loss is nan'})
    assert str(folder.state()) == 'failed (step 2: the loss is nan; checkpoint of step 40)'
    folder.clear_result()
    assert folder.state().name == 'resumable'


@pytest.mark.parametrize('files, state, new_run, resume', [
    ((), 'new', True, False),
    (('config.json', 'log.jsonl'), 'new', True, False),           # killed before its first checkpoint
    (('checkpoint',), 'resumable', False, True),
    (('checkpoint', 'result'), 'finished', False, True),
    (('checkpoint', 'failure'), 'failed', False, True),
    (('config.json', 'failure'), 'failed', True, False),          # failed before its first checkpoint
], ids=['empty', 'dead_attempt', 'killed', 'finished', 'failed', 'failed_before_checkpoint'])
def test_every_state_says_what_it_takes(tmp_path, files, state, new_run, resume):
    """One reading of the state decides what a new run and --resume may do, and says it."""
    folder = RunFolder(tmp_path)
    for name in files:
        if name == 'checkpoint':
            _checkpoint(folder, 7)
        elif name in ('result', 'failure'):
            folder.write_result({'failure': 'step 3: diverging'} if name == 'failure' else {'iterations': 9})
        else:
            (tmp_path / name).write_text('{}')
    found = folder.state()
    assert (found.name, found.takes_new_run, found.takes_resume) == (state, new_run, resume)
    refused = 'nothing to resume' if new_run else 'already holds a run'
    with pytest.raises(ReneusError, match=refused) as err:
        folder.check_start(resume=new_run)
    assert found.advice() in str(err.value) and str(found) in str(err.value)
    assert folder.check_start(resume=resume) == found
    with folder.lock(), pytest.raises(ReneusError, match='in use by process'):
        folder.check_start(resume=resume)


def _log(path, steps, torn=False):
    text = ''.join(json.dumps({'iteration': i, 'psnr': 20.0 + i}) + '\n' for i in steps)
    path.write_text(text + ('{"iteration": 9, "ps' if torn else ''))


def test_repair_log(tmp_path):
    path = tmp_path / 'log.jsonl'
    _log(path, range(1, 9), torn=True)
    entries = RunFolder(tmp_path).repair_log(6)
    assert [e['iteration'] for e in entries] == list(range(1, 7))
    assert [json.loads(line)['iteration'] for line in path.read_text().splitlines()] == list(range(1, 7))
    _log(path, [1, 2, 5, 6])
    with pytest.warns(UserWarning, match=r'no log line for 2 of the 6 steps .* \[3, 4\]'):
        RunFolder(tmp_path).repair_log(6)
    path.write_text('{"iteration": 1}\ngarbage\n{"iteration": 2}\n')
    with pytest.raises(ReneusError, match="line 2 is not a log entry"):
        RunFolder(tmp_path).repair_log(2)
    assert recent_psnr([{'psnr': 10.0}, {'psnr': 20.0}, {'psnr': 30.0}], n=2) == 25.0
    assert recent_psnr([]) is None


def test_stray_temporaries(tmp_path):
    """A kill inside an atomic write leaves a temporary that the next start removes."""
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(tmp_path / 'checkpoint.npz') as tmp:
            open(tmp, 'wb').write(b'half')
            raise KeyboardInterrupt
    assert os.listdir(tmp_path) == []
    (tmp_path / '.tmp-abc.npz').write_bytes(b'left by SIGKILL')
    atomic_write_text(tmp_path / 'log.jsonl', '')
    assert RunFolder(tmp_path).remove_stray_temporaries() == ['.tmp-abc.npz']
    assert os.listdir(tmp_path) == ['log.jsonl']
