"""The run folder: its checks, its lock, its log, its state read from disk."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import reneus_mi

from reneus_mi.train.run_folder import RunFolder, RunState, recent_psnr
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_path, atomic_write_text


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


def _holder(path) -> str:
    return (path / '.lock').read_text().split()[0]


def test_run_lock(tmp_path):
    with RunFolder(tmp_path).lock():
        assert _holder(tmp_path) == str(os.getpid())
        with RunFolder(tmp_path).lock():          # nested in the process that holds it
            pass
        assert RunFolder(tmp_path).lock().owner() == f'process {os.getpid()}'
    assert not (tmp_path / '.lock').exists()
    # A lock file left by a killed process (no kernel lock on it) is taken over.
    dead = subprocess.run([sys.executable, '-c', 'import os; print(os.getpid())'],
                          capture_output=True, text=True).stdout.strip()
    (tmp_path / '.lock').write_text(dead)
    assert RunFolder(tmp_path).state().name == 'new'
    with RunFolder(tmp_path).lock():
        assert _holder(tmp_path) == str(os.getpid())


# The lock needs no Mitsuba: its processes import the modules without the package's
# __init__ (which loads Mitsuba), so that they start in a fraction of a second.
_HOLD = """
import os, sys, time, types
for name in ('reneus_mi', 'reneus_mi.train'):
    sys.modules[name] = types.ModuleType(name)
    sys.modules[name].__path__ = [os.path.join(sys.argv[4], *name.split('.'))]
from reneus_mi.train.run_folder import RunLock
from reneus_mi.utils.errors import ReneusError
print('ready', flush=True)
while not os.path.exists(sys.argv[2]):
    pass
hold, end = float(sys.argv[3]), time.monotonic() + float(sys.argv[5])
while True:
    try:
        with RunLock(sys.argv[1]):
            got = time.monotonic()
            print('got', flush=True)
            time.sleep(hold)
            print('held', got, time.monotonic(), flush=True)
    except ReneusError as e:
        print('refused', e, flush=True)
    if time.monotonic() > end:
        break
"""


def _holders(folder, n, hold, repeat=0.0):
    """``n`` processes that ask for the lock of ``folder`` at the same instant, each holding
    it ``hold`` seconds once it has it, and asking again for ``repeat`` seconds."""
    go = folder / 'go'
    root = os.path.dirname(os.path.dirname(reneus_mi.__file__))
    procs = [subprocess.Popen([sys.executable, '-c', _HOLD, str(folder / '.lock'), str(go), str(hold), root, str(repeat)],
                              stdout=subprocess.PIPE, text=True) for _ in range(n)]
    for p in procs:
        assert p.stdout.readline() == 'ready\n'
    go.write_text('')
    return procs


def test_run_lock_two_processes_at_once(tmp_path):
    """Of processes that ask at the same instant, one gets the lock and the others are told
    who holds it; asking again and again for 3 s, no two ever hold it at once."""
    procs = _holders(tmp_path, 6, hold=1.0)
    outs = [p.communicate(timeout=60)[0] for p in procs]
    got = [o for o in outs if o.startswith('got')]
    assert len(got) == 1, outs
    assert all(o.startswith('refused') and 'in use by process' in o for o in outs if o not in got), outs
    procs = _holders(tmp_path, 6, hold=0.002, repeat=3.0)
    held = sorted(tuple(map(float, line.split()[1:])) for p in procs
                  for line in p.communicate(timeout=60)[0].splitlines() if line.startswith('held'))
    assert len(held) > 20
    overlaps = [(a, b) for a, b in zip(held, held[1:]) if b[0] < a[1]]
    assert not overlaps, f'{len(overlaps)} of {len(held)} holds overlap another'


def test_run_lock_of_a_killed_process(tmp_path):
    """The kernel drops a SIGKILLed holder's lock: the run is no longer 'running'."""
    import signal
    (proc,) = _holders(tmp_path, 1, hold=600.0)
    assert proc.stdout.readline().startswith('got')
    assert RunFolder(tmp_path).state() == RunState('running', f'process {proc.pid}')
    with pytest.raises(ReneusError, match=f'in use by process {proc.pid}'):
        RunFolder(tmp_path).lock().acquire()
    with pytest.raises(ReneusError, match=f'run is in use by process {proc.pid}'):
        RunFolder(tmp_path).check_start(resume=True)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert (tmp_path / '.lock').exists() and RunFolder(tmp_path).state().name == 'new'
    with RunFolder(tmp_path).lock():
        assert _holder(tmp_path) == str(os.getpid())


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
    with folder.lock():       # the holder itself (a batch worker preparing the run) reads the files
        assert folder.check_start(resume=resume) == found


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
