"""python -m reneus_mi.optimize end to end: kill and resume, bad datasets, a time budget, --set.

Tiny runs on the tiny dataset (``tiny.py``: its settings and tolerances): a field
of width 16, 8 + 8 samples, 64 rays per step, 8 steps.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh

from reneus_mi import extract, optimize
from reneus_mi.train import checkpoint
from tiny import assert_same_state, file_state

ITERATIONS = 8
CLI_TRAIN = ['--iterations', str(ITERATIONS), '--checkpoint-every', '2', '--batch-rays', '64',
             '--warm-up', '2', '--validate-every', '0', '--mesh-resolution', '16', '--quiet']


def cli(*args, one_core=False, **kwargs):
    env = {**os.environ, 'RENEUS_VARIANT': 'llvm_ad_rgb'}
    if one_core:  # Dr.Jit then runs one thread: float sums in one order, runs bitwise equal
        first = min(os.sched_getaffinity(0))
        kwargs['preexec_fn'] = lambda: os.sched_setaffinity(0, {first})
    return subprocess.Popen([sys.executable, '-m', 'reneus_mi.optimize', *map(str, args)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            **kwargs)


def finish(proc, timeout=300):
    out, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, f'exit {proc.returncode}\n{out}\n{err}'
    return out, err


def logged(path) -> list[int]:
    """Iterations of the complete lines of a log.jsonl."""
    its = []
    if os.path.isfile(path):
        with open(path) as f:
            for line in f:
                try:
                    its.append(json.loads(line)['iteration'])
                except ValueError:
                    pass  # a line being written
    return its


# ---------------------------------------------------------------- kill/resume
def test_sigkill_then_resume_matches_unbroken_run(scene_xml, tmp_path):
    unbroken, broken = tmp_path / 'unbroken', tmp_path / 'broken'
    reference = cli(scene_xml, '-o', unbroken, *CLI_TRAIN, one_core=True)
    finish(reference)

    proc = cli(scene_xml, '-o', broken, *CLI_TRAIN, one_core=True)
    # Kill it at an odd iteration: after the checkpoint of the step before,
    # so the log holds a step that the checkpoint does not.
    deadline = time.monotonic() + 240
    while True:
        its = logged(broken / 'log.jsonl')
        if its and its[-1] % 2 == 1 and its[-1] >= 3:
            break
        assert proc.poll() is None, f'finished before it was killed: {proc.communicate()}'
        assert time.monotonic() < deadline, 'no progress'
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    killed_log = logged(broken / 'log.jsonl')
    saved_at = checkpoint.load_meta(str(broken / 'checkpoint.npz'))['iteration']
    assert saved_at < killed_log[-1] < ITERATIONS, (saved_at, killed_log)
    with open(broken / 'log.jsonl') as f:
        kept_lines = [line for line in f if json.loads(line)['iteration'] <= saved_at]

    out, _ = finish(cli('-o', broken, '--resume', '--quiet', one_core=True))
    assert f'done: {ITERATIONS} iterations' in out

    # No step missing, none twice; the lines up to the checkpoint are untouched.
    assert logged(broken / 'log.jsonl') == list(range(1, ITERATIONS + 1))
    with open(broken / 'log.jsonl') as f:
        assert f.readlines()[:saved_at] == kept_lines
    assert logged(unbroken / 'log.jsonl') == list(range(1, ITERATIONS + 1))

    for run in (unbroken, broken):
        assert checkpoint.load_meta(str(run / 'checkpoint.npz'))['iteration'] == ITERATIONS
    a, b = file_state(unbroken / 'checkpoint.npz'), file_state(broken / 'checkpoint.npz')
    assert_same_state(a, b, exact=True)
    with open(unbroken / 'config.json') as f, open(broken / 'config.json') as g:
        assert json.load(f)['train'] == json.load(g)['train']

    # The final checkpoint is the state the final mesh was made from: the
    # extract CLI at the same resolution gives the same mesh.
    again = tmp_path / 'again.ply'
    assert extract.main([str(broken / 'checkpoint.npz'), '-o', str(again), '--resolution', '16']) == 0
    mesh, final = trimesh.load(again, process=False), trimesh.load(broken / 'mesh.ply', process=False)
    assert mesh.vertices.shape == final.vertices.shape
    assert np.abs(mesh.vertices - final.vertices).max() < 1e-6


# ----------------------------------------------------------------- bad input
def snapshot(folder) -> dict:
    files = {}
    for root, _, names in os.walk(folder):
        for name in names:
            path = os.path.join(root, name)
            with open(path, 'rb') as f:
                files[os.path.relpath(path, folder)] = f.read()
    return files


def run_main(args) -> str:
    """``optimize.main`` must exit with ``error: ...``; return that message."""
    with pytest.raises(SystemExit) as exit_info:
        optimize.main([str(a) for a in args])
    message = exit_info.value.code
    assert isinstance(message, str) and message.startswith('error: '), message
    assert 'Traceback' not in message
    return message


def _frames(folder):
    with open(folder / 'transforms.json') as f:
        return json.load(f)


def _write_frames(folder, meta):
    with open(folder / 'transforms.json', 'w') as f:
        json.dump(meta, f)


def missing_image(folder):
    os.remove(folder / 'images' / 'r_003.png')
    return [r'frames[3]', 'r_003', 'missing']


def unreadable_image(folder):
    (folder / 'images' / 'r_005.png').write_bytes(b'\x89PNG\r\n\x1a\n this is not an image')
    return ['r_005.png', 'unreadable image']


def singular_camera(folder):
    meta = _frames(folder)
    meta['frames'][4]['transform_matrix'] = [[1, 0, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    _write_frames(folder, meta)
    return ['transforms.json', 'frames[4]', 'transform_matrix', 'not invertible']


def no_container(folder):
    meta = _frames(folder)
    del meta['mesh_outside']
    _write_frames(folder, meta)
    return ['transforms.json', 'no container mesh', 'mesh_outside']


def open_container(folder):
    box = trimesh.load(folder / 'container.ply', force='mesh')
    box.update_faces(np.arange(len(box.faces)) != 0)   # drop one triangle
    box.export(folder / 'container.ply')
    return [str(folder / 'container.ply'), 'not closed']


def image_count(folder):
    """NeuS format: one image fewer than cameras."""
    os.remove(sorted((folder / 'image').iterdir())[-1])
    return [str(folder / 'image'), 'has 11 images', 'cameras_sphere.npz', '12 cameras']


BAD_DATA = {'missing_image': ('box', missing_image), 'unreadable_image': ('box', unreadable_image),
            'singular_camera': ('box', singular_camera), 'no_container': ('box', no_container),
            'open_container': ('box', open_container), 'image_count': ('box_neus', image_count)}


@pytest.fixture
def output(tmp_path):
    """An output folder that already holds files (but no run)."""
    out = tmp_path / 'out'
    (out / 'images').mkdir(parents=True)
    (out / 'config.json').write_text('{"sentinel": true}')
    (out / 'log.jsonl').write_text('{"iteration": 1}\n')
    (out / 'images' / 'keep.png').write_bytes(b'png')
    return out


@pytest.mark.parametrize('case', sorted(BAD_DATA))
def test_bad_dataset_names_the_file_and_writes_nothing(scene_xml, tmp_path, output, case):
    subset, mutate = BAD_DATA[case]
    data = tmp_path / 'data'
    shutil.copytree(os.path.join(os.path.dirname(scene_xml), subset), data)
    expected = mutate(data)
    before = snapshot(output)
    message = run_main([scene_xml, '--data', data, '-o', output, *CLI_TRAIN])
    for part in expected:
        assert part in message, f'{part!r} not in {message!r}'
    assert snapshot(output) == before


def test_scene_without_reneus_integrator(scene_xml, tmp_path, output):
    with open(scene_xml) as f:
        xml = f.read()
    start, end = xml.index('<integrator'), xml.index('</integrator>') + len('</integrator>')
    xml = xml[:start] + '<integrator type="path"/>' + xml[end:]
    scene = tmp_path / 'path_scene.xml'
    scene.write_text(xml.replace('<string name="filename" value="box/',
                                 f'<string name="filename" value="{os.path.dirname(scene_xml)}/box/'))
    before = snapshot(output)
    message = run_main([scene, '-o', output, *CLI_TRAIN])
    assert str(scene) in message and 'expected <integrator type="reneus">' in message
    assert snapshot(output) == before


def test_output_holding_a_run_needs_resume(scene_xml, tmp_path):
    out = tmp_path / 'run'
    train = [a if a != str(ITERATIONS) else '2' for a in CLI_TRAIN]
    assert optimize.main([scene_xml, '-o', str(out), *train]) == 0
    before = snapshot(out)
    assert {'checkpoint.npz', 'config.json', 'log.jsonl', 'mesh.ply'} <= set(before)
    message = run_main([scene_xml, '-o', out, *CLI_TRAIN])
    assert str(out) in message and 'already holds a run' in message and '--resume' in message
    assert snapshot(out) == before
    # --resume of a folder without a run says so too.
    message = run_main(['-o', tmp_path / 'empty', '--resume'])
    assert str(tmp_path / 'empty') in message and 'nothing to resume' in message


def test_cli_error_has_no_traceback(scene_xml, tmp_path):
    """The same through a real process: one line on stderr, exit status 1."""
    data = tmp_path / 'data'
    shutil.copytree(os.path.join(os.path.dirname(scene_xml), 'box'), data)
    missing_image(data)
    proc = cli(scene_xml, '--data', data, '-o', tmp_path / 'out', *CLI_TRAIN)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1
    assert 'Traceback' not in err and err.startswith('error: ') and 'r_003' in err
    assert not (tmp_path / 'out').exists()


def test_time_budget_stops_with_a_mesh(scene_xml, tmp_path):
    """--max-minutes ends training early with the final checkpoint, the mesh and a message saying so.

    The field must have a surface whenever the budget ends, however many steps this machine
    managed: a learning rate of 1e-9 keeps the initial sphere (NeuS's geometric init) in place."""
    out = tmp_path / 'run'
    proc = cli(scene_xml, '-o', out, '--iterations', '100000', '--max-minutes', '0.05', '--batch-rays', '64',
               '--learning-rate', '1e-9',
               '--validate-every', '0', '--checkpoint-every', '0', '--mesh-resolution', '16', '--quiet')
    stdout, _ = finish(proc)
    assert 'stopped by the time budget (0.05 min) after' in stdout
    meta = checkpoint.load_meta(str(out / 'checkpoint.npz'))
    done = meta['iteration']
    # The run used its whole budget (and no more than one step beyond it).
    assert meta['elapsed'] >= 3.0
    assert 0 < done < 100000 and logged(out / 'log.jsonl')[-1] == done
    assert len(trimesh.load(out / 'mesh.ply', force='mesh').faces) > 0


def test_set_reaches_the_run(scene_xml, tmp_path):
    """--set takes any setting by its dotted path, after the options; config.json records it."""
    out = tmp_path / 'run'
    train = [a if a != str(ITERATIONS) else '1' for a in CLI_TRAIN]
    assert optimize.main([scene_xml, '-o', str(out), *train, '--warm-up', '3', '--set', 'train.warm_up=1',
                          '--set', 'model.sampler.n_coarse=4', '--set', 'train.refine.after=7']) == 0
    config = json.loads((out / 'config.json').read_text())
    assert config['train']['warm_up'] == 1 and config['train']['refine']['after'] == 7
    assert config['model']['sampler']['n_coarse'] == 4
