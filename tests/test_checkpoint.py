"""Checkpoints: resume equals an unbroken run, fixed seeds repeat, atomic writes, NaN stops.

Everything trains a tiny field (width 16, 2 layers, 8 + 8 samples, 64 rays per
step) on a 12-view 16x16 dataset of the statuette in its glass box.

Tolerances. Dr.Jit's reverse mode accumulates the weight gradients with
atomic float adds from parallel threads, so with more than one thread two
identical runs differ in the last bits. Measured on a 2-core machine after 6
steps: field parameters differ by <= 3e-7 (absolute), Adam's moments by
<= 1.2e-5 of their largest magnitude; with one thread every array is bitwise
equal, which the tests assert. The multi-threaded tolerances, 1e-5 on the
parameters and 1e-3 relative on the moments, sit >= 30x and >= 80x above that
noise, and >= 50x and >= 12x below the error of a state one step off (a
checkpoint holding the weights from before the last update gave 5e-4..7e-4
on the parameters, 1.2e-2..1.7e-1 relative on the moments) and further below
another seed's (3.5e-3; 0.16..1.2).
"""
from __future__ import annotations

import glob
import json
import os
import subprocess
import sys

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from reneus_mi import checkpoint, runs
from reneus_mi.config import replace
from reneus_mi.optimize import spec_of_scene
from reneus_mi.trainer import Trainer, TrainingError

PARAM_ATOL = 1e-5
MOMENT_RTOL = 1e-3


def tiny_dataset(root) -> str:
    """Render (once per pytest session folder) the tiny dataset; return its scene XML."""
    from reneus_mi.data import load_dataset
    from reneus_mi.scene import write_scene
    from reneus_mi.synth import make_dataset
    root = str(root)
    data = os.path.join(root, 'box')
    if not os.path.isfile(os.path.join(data, 'transforms.json')):
        make_dataset('statuette', root, views=12, res=16, spp=16, subsets=('box',))
    scene = os.path.join(root, 'scene_tiny.xml')
    if not os.path.isfile(scene):
        write_scene(load_dataset(data), scene, preset='tiny')
    return scene


@pytest.fixture(scope='module')
def scene_xml(tmp_path_factory):
    return tiny_dataset(tmp_path_factory.getbasetemp() / 'tiny_statuette')


@pytest.fixture
def one_thread():
    old = dr.thread_count()
    dr.set_thread_count(1)
    yield
    dr.set_thread_count(old)


def tiny_spec(scene_xml: str, **train) -> runs.RunSpec:
    """The tiny preset's run of the scene, with training settings changed."""
    spec = spec_of_scene(scene_xml, None)
    spec.config = replace(spec.config, **{f'train.{k}': v for k, v in train.items()})
    return spec


def new_trainer(scene_xml: str, out, **cfg) -> Trainer:
    trainer = runs.make_trainer(tiny_spec(scene_xml, **cfg), str(out))
    os.makedirs(str(out), exist_ok=True)
    return trainer


def train_state(trainer: Trainer) -> dict:
    """Parameters, Adam moments and step counts of the optimiser, by the field's names."""
    state = {}
    for key in trainer.opt.keys():
        name = trainer._name(key)
        _, _, _, (t, m, v, _) = trainer.opt.state[key]
        state[f'param/{name}'] = np.array(trainer.opt[key]).ravel()
        state[f'adam/{name}/m'] = np.array(m).ravel()
        state[f'adam/{name}/v'] = np.array(v).ravel()
        state[f'adam/{name}/t'] = np.array(t).ravel().astype(np.int64)
    return state


def file_state(path) -> dict:
    """The same arrays read from a checkpoint file (refined surroundings as parameters)."""
    with np.load(str(path), allow_pickle=False) as f:
        return {k.replace('surroundings/', 'param/'): f[k] for k in f.files
                if k.startswith(('param/', 'adam/', 'surroundings/'))}


def differences(a: dict, b: dict) -> dict:
    """Largest difference per array: absolute for parameters, relative to max|a| for moments."""
    assert sorted(a) == sorted(b)
    out = {}
    for k in a:
        assert a[k].shape == b[k].shape, k
        d = float(np.max(np.abs(a[k].astype(np.float64) - b[k]))) if a[k].size else 0.0
        if k.startswith('adam/') and not k.endswith('/t'):
            d /= max(float(np.max(np.abs(a[k]))), 1e-30)
        out[k] = d
    return out


def assert_same_state(a: dict, b: dict, *, exact: bool) -> None:
    if exact:
        unequal = [k for k in a if not np.array_equal(a[k], b[k])]
        assert not unequal, f'not bitwise equal: {unequal}; differences {differences(a, b)}'
        return
    diff = differences(a, b)
    for k, d in diff.items():
        tol = 0 if k.endswith('/t') else PARAM_ATOL if k.startswith('param/') else MOMENT_RTOL
        assert d <= tol, f'{k}: difference {d:.3g} > {tol}; all: {diff}'


def run_steps(trainer: Trainer, n: int) -> None:
    for _ in range(n):
        trainer.step()


# --------------------------------------------------------------------- resume
N = 3


def _resume_vs_unbroken(scene_xml, tmp_path, **cfg):
    unbroken = new_trainer(scene_xml, tmp_path / 'unbroken', **cfg)
    run_steps(unbroken, 2 * N)

    first = new_trainer(scene_xml, tmp_path / 'broken', **cfg)
    run_steps(first, N)
    first.save_checkpoint()
    # The checkpoint holds the optimiser's weights after the N-th update.
    state, saved = train_state(first), file_state(first.checkpoint_path)
    # The surroundings are saved whether refined or not (the IOR always).
    assert set(state) <= set(saved)
    assert_same_state(state, {k: v for k, v in saved.items() if k in state}, exact=True)
    del first  # killed

    resumed = new_trainer(scene_xml, tmp_path / 'broken', **cfg)
    resumed.resume()
    assert resumed.iteration == N
    run_steps(resumed, N)
    assert resumed.iteration == unbroken.iteration == 2 * N
    assert resumed.best_loss == pytest.approx(unbroken.best_loss, rel=1e-5)
    return train_state(unbroken), train_state(resumed)


def test_resume_is_bitwise_with_one_thread(scene_xml, tmp_path, one_thread):
    a, b = _resume_vs_unbroken(scene_xml, tmp_path)
    assert_same_state(a, b, exact=True)


def test_resume_matches_unbroken_run(scene_xml, tmp_path):
    a, b = _resume_vs_unbroken(scene_xml, tmp_path)
    assert_same_state(a, b, exact=False)
    # The steps moved the weights by far more than the tolerance.
    init = new_trainer(scene_xml, tmp_path / 'init')
    moved = differences(a, train_state(init))
    assert min(moved[f'param/{init._name(k)}'] for k in init.opt.keys()) > 30 * PARAM_ATOL


def test_resume_of_a_refining_run_matches_unbroken_run(scene_xml, tmp_path):
    # IOR, pose (with the silhouette term), SH light and a sample budget: their values, Adam
    # states and the batch size come back from the checkpoint.
    refine = dict(refine_ior=True, refine_pose=True, refine_light='sh', refine_after=0,
                  sample_budget=2000, batch_rays=64)
    a, b = _resume_vs_unbroken(scene_xml, tmp_path, **refine)
    assert {'param/container.eta', 'param/container.translation', 'param/light.sh'} <= set(a)
    assert_same_state(a, b, exact=False)
    init = new_trainer(scene_xml, tmp_path / 'init', **refine)
    moved = differences(a, train_state(init))
    assert moved['param/container.translation'] > 30 * PARAM_ATOL


# ----------------------------------------------------------------------- seed
def _two_runs(scene_xml, tmp_path, seed_b=0):
    a = new_trainer(scene_xml, tmp_path / 'a', seed=0)
    b = new_trainer(scene_xml, tmp_path / 'b', seed=seed_b)
    run_steps(a, 2 * N)
    run_steps(b, 2 * N)
    return train_state(a), train_state(b)


def test_fixed_seed_is_bitwise_with_one_thread(scene_xml, tmp_path, one_thread):
    a, b = _two_runs(scene_xml, tmp_path)
    assert_same_state(a, b, exact=True)


def test_fixed_seed_repeats_and_another_seed_differs(scene_xml, tmp_path):
    a, b = _two_runs(scene_xml, tmp_path)
    assert_same_state(a, b, exact=False)
    a, c = _two_runs(scene_xml, tmp_path / 'other', seed_b=1)
    diff = differences(a, c)
    assert max(d for k, d in diff.items() if k.startswith('param/')) > 30 * PARAM_ATOL
    assert max(d for k, d in diff.items() if k.startswith('adam/') and not k.endswith('/t')) \
        > 30 * MOMENT_RTOL


# -------------------------------------------------------------------- atomic
def test_failed_write_leaves_previous_checkpoint(scene_xml, tmp_path, monkeypatch):
    trainer = new_trainer(scene_xml, tmp_path)
    run_steps(trainer, 2)
    trainer.save_checkpoint()
    path = trainer.checkpoint_path
    with open(path, 'rb') as f:
        before = f.read()
    run_steps(trainer, 1)

    real_savez = np.savez

    def torn_savez(file, *args, **kwargs):
        # Write part of a real archive, then fail as a full disk would.
        import io
        buf = io.BytesIO()
        real_savez(buf, *args, **kwargs)
        file.write(buf.getvalue()[:len(buf.getvalue()) // 2])
        file.flush()
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(np, 'savez', torn_savez)
    with pytest.raises(OSError, match='No space left'):
        trainer.save_checkpoint()
    monkeypatch.undo()

    with open(path, 'rb') as f:
        assert f.read() == before
    assert sorted(os.listdir(tmp_path)) == ['checkpoint.npz']  # no temporary file left
    assert checkpoint.load_meta(path)['iteration'] == 2
    resumed = new_trainer(scene_xml, tmp_path)
    resumed.resume()
    assert resumed.iteration == 2


# ----------------------------------------------------------------------- NaN
def poison_run(scene_xml, out, where: str, at: int = 3, monkeypatch=None) -> Trainer:
    """A trainer (checkpoint every step) whose ``where`` turns NaN from step ``at`` on.

    ``where``: 'radiance' or 'geometry' (the field's outputs), or 'loss' (the
    colour loss itself; needs ``monkeypatch``). The NaN enters as an opaque
    factor, so the kernels do not change when it does.
    """
    from reneus_mi import losses
    trainer = new_trainer(scene_xml, out, iterations=6, checkpoint_every=1)
    poison = {'factor': dr.opaque(mi.Float, 1.0)}
    field = trainer.field
    if where == 'loss':
        color_l1 = losses.color_l1
        monkeypatch.setattr(losses, 'color_l1', lambda *a: color_l1(*a) * poison['factor'])
    elif where == 'radiance':
        radiance = field.radiance
        field.radiance = lambda *a: radiance(*a) * poison['factor']
    else:
        geometry = field.geometry
        field.geometry = lambda x: (lambda g: (g[0] * poison['factor'], g[1]))(geometry(x))
        field.sdf = lambda x: field.geometry(x)[0]
    step = trainer.step

    def poisoned_step():
        if trainer.iteration == at:
            poison['factor'] = dr.opaque(mi.Float, float('nan'))
        return step()

    trainer.step = poisoned_step
    return trainer


@pytest.mark.parametrize('where, message', [
    ('loss', r'^step 3: the loss is nan; stopped before updating'),
    # NaN radiance: the tonemap's clamp (dr.maximum(L, 1e-6), which maps NaN
    # to 1e-6 on LLVM) hides it from the loss, not from the gradient.
    ('radiance', r"^step 3: the gradient of '[a-z.]+' is not finite; stopped before updating"),
])
def test_nan_stops_naming_the_step_and_keeps_checkpoint(scene_xml, tmp_path, where, message,
                                                         monkeypatch):
    trainer = poison_run(scene_xml, tmp_path, where, monkeypatch=monkeypatch)
    with pytest.raises(TrainingError, match=message) as err:
        trainer.run(progress=False)
    assert trainer.checkpoint_path in str(err.value)
    assert trainer.iteration == 3

    # The checkpoint of step 3 (after updates 0..2) is on disk, finite, and is
    # exactly what the optimiser holds: the NaN step updated nothing.
    assert checkpoint.load_meta(trainer.checkpoint_path)['iteration'] == 3
    on_disk = file_state(trainer.checkpoint_path)
    assert all(np.all(np.isfinite(v)) for v in on_disk.values())
    assert_same_state(train_state(trainer), on_disk, exact=True)
    with open(tmp_path / 'log.jsonl') as f:
        assert [json.loads(line)['iteration'] for line in f] == [1, 2, 3]
    assert not glob.glob(str(tmp_path / '*.tmp'))


def test_nan_geometry_stops_with_training_error(scene_xml, tmp_path):
    """In a subprocess, as it once crashed the process: a NaN SDF makes every
    transmittance NaN, so no ray survives the first interface."""
    code = (
        'import sys; sys.path.insert(0, sys.argv[1]); import conftest\n'
        'from test_checkpoint import poison_run\n'
        'from reneus_mi.trainer import TrainingError\n'
        'try:\n'
        '    poison_run(sys.argv[2], sys.argv[3], "geometry").run(progress=False)\n'
        'except TrainingError as e:\n'
        '    print(e); sys.exit(3)\n')
    proc = subprocess.run([sys.executable, '-c', code, os.path.dirname(__file__), scene_xml,
                           str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 3, f'exit {proc.returncode}: {proc.stderr[-2000:]}'
    assert proc.stdout.startswith('step 3: ')
    assert checkpoint.load_meta(str(tmp_path / 'checkpoint.npz'))['iteration'] == 3


def test_loss_scaler_state_survives_a_checkpoint(scene_xml, tmp_path):
    """The CUDA path's GradScaler (float16 networks): its scale and growth counter are
    checkpointed, so a resumed run scales its loss as the unbroken one (checked on the CPU)."""
    from drjit.opt import GradScaler
    trainer = new_trainer(scene_xml, tmp_path)
    trainer.scaler = GradScaler(init_scale=mi.Float(2.0 ** 16))
    trainer.scaler.scale_factor = mi.Float(1024.0)
    trainer.scaler.it = 7
    trainer.save_checkpoint()
    resumed = new_trainer(scene_xml, tmp_path)
    resumed.scaler = GradScaler(init_scale=mi.Float(2.0 ** 16))
    names = {key: resumed._name(key) for key in resumed.opt.keys()}
    checkpoint.restore(resumed.checkpoint_path, resumed.opt, names, resumed.scaler)
    assert float(resumed.scaler.scale_factor[0]) == 1024.0 and resumed.scaler.it == 7


def test_time_budget_shapes_the_schedules(scene_xml, tmp_path):
    # Under a budget the schedules follow the share of it spent, laid over the planned
    # iterations: half the budget spent is the middle of the learning-rate decay and of
    # the annealing, whatever step the run is at.
    trainer = new_trainer(scene_xml, tmp_path / 'run', iterations=400, max_minutes=1.0, warm_up=10,
                          anneal_end=400)
    assert trainer.schedule_step() == 0
    trainer.elapsed = 30.0
    stats = trainer.step()
    cfg = trainer.cfg
    assert trainer.iteration == 1 and trainer.integrator.state.schedule == 200
    assert stats.learning_rate == pytest.approx(cfg.learning_rate_at(200))
    assert trainer.integrator.state.cos_anneal_ratio == pytest.approx(0.5)
    trainer.elapsed = 120.0
    assert trainer.schedule_step() == 400
    # Without a budget the schedule is the step.
    plain = new_trainer(scene_xml, tmp_path / 'plain', iterations=400)
    plain.elapsed = 30.0
    assert plain.schedule_step() == 0
