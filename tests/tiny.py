"""The tiny statuette dataset and trainers on it, shared by the tests.

The dataset: 12 views at 16x16 of the statuette in its glass box, rendered once
per pytest session (``conftest.scene_xml``); the trainers train the ``tiny``
preset's field (width 16, 2 layers, 8 + 8 samples, 64 rays per step) on it.

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

import os

import drjit as dr
import mitsuba as mi
import numpy as np

from reneus_mi.config import replace
from reneus_mi import runs
from reneus_mi.runs import spec_of_scene
from reneus_mi.train.trainer import Trainer

PARAM_ATOL = 1e-5
MOMENT_RTOL = 1e-3


def tiny_dataset(root, container: str = 'box') -> str:
    """Render (once per pytest session folder) the tiny dataset, the statuette in ``container``
    (a solid ``box``, a glass ``case``); return its scene XML."""
    from reneus_mi.data import load_dataset
    from reneus_mi.data.scene_xml import write_scene
    from reneus_mi.data.synthetic import make_dataset
    root = str(root)
    data = os.path.join(root, 'box')
    if not os.path.isfile(os.path.join(data, 'transforms.json')):
        make_dataset('statuette', root, views=12, res=16, spp=16, subsets=('box',), container=container)
    scene = os.path.join(root, 'scene_tiny.xml')
    if not os.path.isfile(scene):
        write_scene(load_dataset(data), scene, preset='tiny')
    return scene


def tiny_spec(scene_xml: str, **train) -> runs.RunSpec:
    """The record of the tiny preset's run of the scene, with training settings changed (for
    a collection: :func:`reneus_mi.runs.run_many`)."""
    spec = spec_of_scene(scene_xml, None)
    spec.config = replace(spec.config, **{f'train.{k}': v for k, v in train.items()})
    return spec


def tiny_run(scene_xml: str, out, *, start: str = 'new', settings=(), **train) -> runs.Run:
    """The tiny preset's run of the scene in ``out``, prepared as the command prepares it, with
    training fields and ``settings`` (``PATH=VALUE``) changed."""
    return runs.prepare(str(out), scene_xml, train=train, settings=settings, start=start)


def new_trainer(scene_xml: str, out, resume: bool = False, **cfg) -> Trainer:
    """A trainer of the tiny run in ``out`` (from its checkpoint with ``resume``)."""
    trainer = tiny_run(scene_xml, out, start='continue' if resume else 'new', **cfg).trainer()
    os.makedirs(str(out), exist_ok=True)
    return trainer


def train_state(trainer: Trainer) -> dict:
    """Parameters, Adam moments and step counts of the optimiser, by the field's names."""
    state = {}
    for key in trainer.opt.keys():
        name = trainer.names[key]
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


def poison_run(scene_xml, out, where: str, at: int = 3, monkeypatch=None) -> Trainer:
    """A trainer (checkpoint every step) whose ``where`` turns NaN from step ``at`` on.

    ``where``: 'radiance' or 'geometry' (the field's outputs), or 'loss' (the
    colour loss itself; needs ``monkeypatch``). The NaN enters as an opaque
    factor, so the kernels do not change when it does.
    """
    from reneus_mi.train import losses
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
