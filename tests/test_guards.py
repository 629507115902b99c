"""Guards: output places, sizes, the run lock, log repair, whole checkpoints."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from reneus_mi import guards, limits
from reneus_mi.errors import ReneusError, exit_on_error, user_message
from reneus_mi.data.dataset import check_same_dataset, dataset_fingerprint
from reneus_mi.io import atomic_path, atomic_write_text, check_npz_file
from reneus_mi.train.run_folder import RunFolder, recent_psnr
from reneus_mi.train.trainer import training_bytes


def dataset_folder(path):
    path.mkdir(parents=True)
    (path / 'transforms.json').write_text('{}')
    return path


def test_output_file_places(tmp_path):
    data = dataset_folder(tmp_path / 'data')
    with pytest.raises(ReneusError, match='lies in the dataset folder'):
        guards.check_output_file(data / 'sub' / 'x.png')
    scene = tmp_path / 'scene.xml'
    scene.write_text('<scene/>')
    with pytest.raises(ReneusError, match='is or lies inside the input'):
        guards.check_output_file(scene, inputs=[scene], overwrite=True)
    with pytest.raises(ReneusError, match=r'exists; expected a new file name \(or --overwrite'):
        guards.check_output_file(scene)
    assert guards.check_output_file(scene, overwrite=True) == str(scene)
    with pytest.raises(ReneusError, match=r'expected a file ending in .png or .exr'):
        guards.check_output_file(tmp_path / 'x.jpg', extensions=('.png', '.exr'))
    with pytest.raises(ReneusError, match='is a file, expected a folder'):
        guards.check_output_file(scene / 'x.png')
    # A symbolic link into the dataset is the dataset.
    os.symlink(data, tmp_path / 'link')
    with pytest.raises(ReneusError, match='lies in the dataset folder'):
        guards.check_output_file(tmp_path / 'link' / 'x.png')


def test_output_dir_places(tmp_path):
    data = dataset_folder(tmp_path / 'data')
    with pytest.raises(ReneusError, match='lies in the dataset folder'):
        guards.check_output_dir(data)
    (tmp_path / 'parent' / 'photos').mkdir(parents=True)
    with pytest.raises(ReneusError, match='contains the input'):
        guards.check_output_dir(tmp_path / 'parent', inputs=[tmp_path / 'parent' / 'photos'])
    (tmp_path / 'used').mkdir()
    (tmp_path / 'used' / 'a.txt').write_text('a')
    with pytest.raises(ReneusError, match=r'is not empty \(holds a.txt\)'):
        guards.check_output_dir(tmp_path / 'used')
    assert guards.check_output_dir(tmp_path / 'used', allow=('a.txt',)) == str(tmp_path / 'used')
    assert guards.check_output_dir(tmp_path / 'new' / 'deeper') == str(tmp_path / 'new' / 'deeper')
    assert not (tmp_path / 'new').exists()


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


def test_memory_and_indices():
    limits.check_memory(10 * 2**30, 'x', available=16 * 2**30)
    with pytest.raises(ReneusError, match=r'x: needs about 14 GiB, but this machine has 16 GiB'):
        limits.check_memory(14 * 2**30, 'x', available=16 * 2**30)
    limits.check_index_range(2**32 - 1, 'n')
    with pytest.raises(ReneusError, match='n: 4294967296 elements .* 32-bit index limit'):
        limits.check_index_range(2**32, 'n')
    assert limits.physical_memory() > 2**28


def test_training_bytes_is_a_floor_of_the_measured_cost():
    # Measured: 96 B per sample slot (see trainer.BYTES_PER_SAMPLE_SLOT).
    assert training_bytes(32768 - 1024, 16, 3) < (407176 - 263352) * 1024
    assert training_bytes(2048, 16, 3) == 2 * training_bytes(1024, 16, 3)


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


def test_run_state_is_read_from_disk(tmp_path):
    folder = RunFolder(tmp_path / 'run')
    assert folder.state().name == 'new'
    os.makedirs(folder.path)
    (tmp_path / 'run' / 'config.json').write_text('{}')
    assert folder.state().name == 'new'                  # killed before its first checkpoint
    (tmp_path / 'run' / 'checkpoint.npz').write_text('')
    assert folder.state().name == 'resumable'
    with folder.lock():
        assert str(folder.state()) == f'running (process {os.getpid()})'
    folder.write_result({'iterations': 3})
    assert folder.state().name == 'finished' and folder.read_result() == {'iterations': 3}
    folder.write_result({'failure': 'step 2: the loss is nan'})
    assert str(folder.state()) == 'failed (step 2: the loss is nan)'
    folder.clear_result()
    assert folder.state().name == 'resumable'


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


def test_npz_file(tmp_path):
    path = tmp_path / 'c.npz'
    np.savez(path, meta=np.array('{}'), w=np.zeros(1000))
    check_npz_file(path)
    with pytest.raises(ReneusError, match=r"not a reneus-mi checkpoint \(no header\)"):
        check_npz_file(path, keys=('header',))
    path.write_bytes(path.read_bytes()[:300])
    with pytest.raises(ReneusError, match='not a whole checkpoint'):
        check_npz_file(path)
    with pytest.raises(ReneusError, match='checkpoint file does not exist'):
        check_npz_file(tmp_path / 'none.npz')


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


def test_dataset_fingerprint():
    class DS:
        root, width, height, names = '/d', 4, 3, ['a.png', 'b.png']
        c2w = np.stack([np.eye(4)] * 2)

        def __len__(self):
            return 2
    saved = dataset_fingerprint(DS())
    check_same_dataset(saved, DS(), 'config.json')
    other = DS()
    other.names = ['a.png', 'c.png']
    with pytest.raises(ReneusError, match=r"differs from the run's \(names"):
        check_same_dataset(saved, other, 'config.json')
    moved = DS()
    moved.c2w = moved.c2w.copy()
    moved.c2w[1, 0, 3] = 0.5
    with pytest.raises(ReneusError, match='other camera positions'):
        check_same_dataset(saved, moved, 'config.json')


def test_exit_on_error_is_one_line():
    with pytest.raises(SystemExit) as e:
        with exit_on_error():
            raise ReneusError('a\nb')
    assert e.value.code == 'error: a b'
    with pytest.raises(SystemExit) as e:
        with exit_on_error():
            open('/nonexistent/x')
    assert e.value.code == "error: /nonexistent/x: No such file or directory"
    wrapped = RuntimeError('scene.xml (line 3): Traceback (most recent call last):\n  x\nValueError: bad')
    assert user_message(wrapped) == 'scene.xml (line 3): ValueError: bad'
