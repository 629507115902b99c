"""One owner for the field's parameters and one configuration for a run.

The field's arrays are what ``mi.traverse`` shows and what the optimiser
writes into, whether the loop is the trainer's or a hand-written
``mi.render`` + ``mi.ad.Adam`` one; a run's ``config.json`` rebuilds it.
"""
from __future__ import annotations

import json
import os

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from reneus_mi import runs
from reneus_mi.config import replace
from reneus_mi.errors import user_message
from reneus_mi.presets import PRESETS
from reneus_mi.trainer import next_batch
from test_checkpoint import new_trainer, tiny_dataset, tiny_spec


@pytest.fixture(scope='module')
def scene_xml(tmp_path_factory):
    return tiny_dataset(tmp_path_factory.getbasetemp() / 'tiny_statuette')


def glass_scene(**integrator):
    return mi.load_dict({
        'type': 'scene', 'integrator': {'type': 'reneus', 'id': 'field', **integrator},
        'sensor': {'type': 'perspective', 'fov': 40,
                   'to_world': mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   'film': {'type': 'hdrfilm', 'width': 3, 'height': 3}},
        'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 0.8}},
        'glass': {'type': 'cube', 'bsdf': {'type': 'dielectric', 'int_ior': 1.45}}})


def test_traverse_shows_the_trained_weights(scene_xml, tmp_path):
    trainer = new_trainer(scene_xml, tmp_path, iterations=3)
    own = trainer.field.params()   # mi.traverse also shows the container's IOR, not trained here
    initial = {k: np.array(v) for k, v in mi.traverse(trainer.scene).items()
               if k.startswith('field.') and k[len('field.'):] in own}
    trainer.run(progress=False)
    params = mi.traverse(trainer.scene)
    with np.load(trainer.checkpoint_path) as f:
        for key in initial:
            trained = np.array(params[key]).ravel()
            assert np.array_equal(trained, f[f'param/{key[len("field."):]}'])
            assert np.abs(trained - initial[key].ravel()).max() > 1e-4, key


def test_partial_update_keeps_the_other_keys():
    scene = glass_scene(preset='tiny')
    field = scene.integrator().field
    params = mi.traverse(scene)
    sdf = np.array(params['field.sdf.weights'])
    params['field.variance'] = mi.Float(0.6)
    params.update()
    assert float(field.inv_s()[0]) == pytest.approx(np.exp(6.0), rel=1e-6)
    assert np.array_equal(np.array(field.params()['sdf.weights']), sdf)
    params['field.sdf.weights'] = mi.Float(sdf * 0.5)
    params.update()
    assert float(field.inv_s()[0]) == pytest.approx(np.exp(6.0), rel=1e-6)
    assert np.allclose(np.array(field.params()['sdf.weights']), sdf * 0.5)


def test_hand_written_adam_loop_moves_the_field():
    """The notebook's loop: gradients reach the field through mi.render, updates land in it."""
    scene = glass_scene(preset='tiny', n_coarse=16, n_fine=0)
    params = mi.traverse(scene)
    keys = [k for k in params.keys() if k.startswith('field.')]
    opt = mi.ad.Adam(lr=1e-2, params={k: params[k] for k in keys})
    params.update(opt)
    before = np.array(scene.integrator().field.params()['color.weights'])
    image = mi.render(scene, params, spp=1, seed=0)
    dr.backward(dr.mean(dr.abs(image - 0.3), axis=None))
    assert all(dr.any(dr.grad(opt[k]) != 0) for k in ('field.color.weights', 'field.sdf.weights'))
    opt.step()
    params.update(opt)
    after = np.array(scene.integrator().field.params()['color.weights'])
    assert np.allclose(after, np.array(opt['field.color.weights']))
    assert np.abs(after - before).max() > 1e-3


def test_config_json_rebuilds_the_same_run(scene_xml, tmp_path):
    first = runs.run(tiny_spec(scene_xml, iterations=3), str(tmp_path / 'a'), progress=False)
    spec = runs.read_spec(str(tmp_path / 'a'))
    assert spec.same_run(tiny_spec(scene_xml, iterations=3)) and spec.data_fingerprint['views'] == 12
    again = runs.run(spec, str(tmp_path / 'b'), progress=False)
    assert first['iterations'] == again['iterations'] == 3

    def losses(folder):
        with open(tmp_path / folder / 'log.jsonl') as f:
            return [json.loads(line)['loss'] for line in f]
    # Same seed, same settings: the same losses (up to parallel float sums).
    assert np.allclose(losses('a'), losses('b'), rtol=1e-4)
    # Another seed draws other rays.
    spec.config.train.seed = 1
    runs.run(spec, str(tmp_path / 'c'), progress=False)
    assert not np.allclose(losses('a'), losses('c'), rtol=1e-2)


def test_run_many_skips_finished_runs_and_refuses_changed_ones(scene_xml, tmp_path):
    specs = {'one': tiny_spec(scene_xml, iterations=2)}
    first = runs.run_many(specs, str(tmp_path))
    mtime = os.path.getmtime(tmp_path / 'one' / 'checkpoint.npz')
    assert runs.run_many(specs, str(tmp_path)) == first
    assert os.path.getmtime(tmp_path / 'one' / 'checkpoint.npz') == mtime
    with pytest.raises(ValueError, match='holds a run with other settings'):
        runs.run_many({'one': tiny_spec(scene_xml, iterations=3)}, str(tmp_path))


@pytest.mark.parametrize('name', sorted(PRESETS))
def test_each_preset_loads_and_renders(name):
    scene = glass_scene(preset=name)
    it = scene.integrator()
    assert it.model == PRESETS[name].model
    image = np.array(mi.render(scene, spp=1))
    assert image.shape == (3, 3, 3) and np.all(np.isfinite(image)) and image.min() >= 0


@pytest.mark.parametrize('prop, value, message', [
    ('n_coarse', 'many', "n_coarse='many': expected an integer"),
    ('max_depth', 'two', "max_depth='two': expected an integer"),
    ('field_hidden', 2.5, 'field_hidden=2.5: expected an integer'),
    ('preset', 'huge', "preset='huge'; expected one of"),
    ('field_hiden', 16, "unknown parameter(s) 'field_hiden'"),
])
def test_integrator_settings_are_typed_and_named(prop, value, message):
    with pytest.raises(Exception) as e:
        glass_scene(**{prop: value})
    assert message in user_message(e.value)


def test_resume_on_a_moved_dataset_is_checked(scene_xml, tmp_path):
    import shutil
    from reneus_mi import optimize
    data = os.path.join(os.path.dirname(scene_xml), 'box')
    out = tmp_path / 'run'
    runs.run(tiny_spec(scene_xml, iterations=2), str(out), progress=False)
    moved = tmp_path / 'moved'
    shutil.copytree(data, moved)
    assert runs.read_spec(str(out)).with_data(str(moved)).data == str(moved)
    other = tmp_path / 'other'
    shutil.copytree(data, other)
    meta = json.loads((other / 'transforms.json').read_text())
    meta['frames'] = meta['frames'][:-1]
    (other / 'transforms.json').write_text(json.dumps(meta))
    with pytest.raises(SystemExit, match='not the dataset this run was started on'):
        optimize.main(['-o', str(out), '--resume', '--data', str(other), '--iterations', '3', '--quiet'])


@pytest.mark.parametrize('budget, refine', [(0, False), (60_000, False), (0, True)],
                         ids=['fixed_batch', 'sample_budget', 'refine_ior'])
def test_training_steps_reuse_their_kernels(scene_xml, tmp_path, budget, refine):
    """Per-step values (seeds, annealing, learning rate, open levels, the batch size under a
    sample budget) reach the kernels as data: a literal would compile new kernels every step
    (it once filled ~/.drjit with 97,000 files and slowed steps 7x). A refined IOR sends
    gradients through the ray tree, whose arrays change width every step: their reverse-mode
    scatters must not compile those widths in (they did: a compile every 1-3 steps, refining
    runs 20x slower)."""
    from reneus_mi.scene import write_scene
    from reneus_mi.data import load_dataset
    from reneus_mi.optimize import spec_of_scene
    xml = str(tmp_path / 'fast.xml')
    write_scene(load_dataset(os.path.join(os.path.dirname(scene_xml), 'box')), xml, preset='fast')
    spec = spec_of_scene(xml, None)
    # A refining run's tree takes a new width every step only with batches of a realistic size.
    spec.config = replace(spec.config, **{'train.batch_rays': 1024 if refine else 64 if not budget else 256,
                                          'train.anneal_end': 50, 'train.sample_budget': budget,
                                          'model.sampler.occupancy_update_every': 1000,
                                          'train.refine_ior': refine, 'train.refine_after': 0})
    trainer = runs.make_trainer(spec, str(tmp_path / 'run'))

    sizes = (256, 512, 768)
    for i in range(8):
        if budget:
            # Batches of the sizes a budget makes. Each size compiles some kernels once: Dr.Jit's
            # CPU backend gives every thread its own copy of a scatter-add target of that size.
            trainer.batch = sizes[i % 3]
        trainer.step()
    if budget:   # the budget set the batch from the samples per ray of the last step
        stats = trainer.step()
        assert trainer.batch == next_batch(trainer.cfg, stats.samples / stats.rays)
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory):
        for i in range(12):
            if budget:
                trainer.batch = sizes[i % 3]
            trainer.step()
        new = [k for k in dr.kernel_history() if k.get('type') == dr.KernelType.JIT and not k['cache_hit']]
    # Fewer than one per step: a branch of the ray tree taken for the first time compiles
    # its kernels (measured 0 to 8); a per-step literal compiles at least one every step.
    # Refining: 0 measured; 3 when the tree's widths reached the reverse-mode kernels.
    assert len(new) < (2 if refine else 12), len(new)


def test_sample_budget_sets_the_next_batch():
    from reneus_mi.config import TrainConfig
    cfg = TrainConfig(batch_rays=1024, sample_budget=40_960)
    assert next_batch(cfg, 40.0) == 1024
    assert next_batch(cfg, 10.0) == 4096            # empty space skipped: more rays
    assert next_batch(cfg, 1.0) == 8192             # at most 8x
    assert next_batch(cfg, 1000.0) == 256           # at least 1/8 (and one quantum)
    assert next_batch(cfg, 33.0) % 256 == 0
