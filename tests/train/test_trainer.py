"""The trainer: it writes into the field's own arrays (what ``mi.traverse`` shows), its
parameter groups start at their steps within their bounds, its steps reuse their kernels,
a sample budget sets the batch, its memory floor, the sharpness under its cap.
"""
from __future__ import annotations

import math
import os

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from reneus_mi.config import TrainConfig
from reneus_mi import runs
from reneus_mi.train.trainer import next_batch, training_bytes
from reneus_mi.utils.errors import ReneusError
from tiny import new_trainer, tiny_dataset, tiny_run


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


@pytest.mark.parametrize('budget, refine', [(0, False), (60_000, False), (0, True)],
                         ids=['fixed_batch', 'sample_budget', 'refine_ior'])
def test_training_steps_reuse_their_kernels(scene_xml, tmp_path, budget, refine):
    """Per-step values (seeds, annealing, learning rate, open levels, the batch size under a
    sample budget) reach the kernels as data: a literal would compile new kernels every step
    (it once filled ~/.drjit with 97,000 files and slowed steps 7x). A refined IOR sends
    gradients through the ray tree, whose arrays change width every step: their reverse-mode
    scatters must not compile those widths in (they did: a compile every 1-3 steps, refining
    runs 20x slower)."""
    from reneus_mi.data.scene_xml import write_scene
    from reneus_mi.data import load_dataset
    xml = str(tmp_path / 'fast.xml')
    write_scene(load_dataset(os.path.join(os.path.dirname(scene_xml), 'box')), xml, preset='fast')
    # A refining run's tree takes a new width every step only with batches of a realistic size.
    trainer = runs.prepare(str(tmp_path / 'run'), xml, settings=['model.sampler.occupancy_update_every=1000'],
                           train={'batch_rays': 1024 if refine else 64 if not budget else 256, 'anneal_end': 50,
                                  'sample_budget': budget, 'refine.ior': refine, 'refine.after': 0}).trainer()

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


    from reneus_mi.config import TrainConfig
    cfg = TrainConfig(batch_rays=1024, sample_budget=40_960)
    assert next_batch(cfg, 40.0) == 1024
    assert next_batch(cfg, 10.0) == 4096            # empty space skipped: more rays
    assert next_batch(cfg, 1.0) == 8192             # at most 8x
    assert next_batch(cfg, 1000.0) == 256           # at least 1/8 (and one quantum)
    assert next_batch(cfg, 33.0) % 256 == 0


def test_groups_start_at_their_step_and_keep_their_bounds(scene_xml, tmp_path):
    """The field moves from step 0; the refined IOR is held until refine.after, then moves at
    its own rate within refine.ior_range."""
    trainer = new_trainer(scene_xml, tmp_path, **{'refine.ior': True, 'refine.after': 2,
                                                  'refine.ior_learning_rate': 0.5,
                                                  'refine.ior_range': (1.40, 1.46)})
    assert [g.name for g in trainer.groups] == ['field', 'ior']
    assert trainer.groups[1].start == 2 and trainer.groups[1].bounds == (1.40, 1.46)
    eta = lambda: float(np.array(trainer.opt[trainer.keys['container.eta']])[0])  # noqa: E731
    sdf = lambda: np.array(trainer.opt[trainer.keys['sdf.weights']])  # noqa: E731
    start, weights = eta(), sdf()
    trainer.step()
    trainer.step()
    assert eta() == start and np.abs(sdf() - weights).max() > 0
    trainer.step()
    # A step of 0.5 leaves the range: the IOR stops at its bound.
    assert min(abs(eta() - 1.40), abs(eta() - 1.46)) < 1e-6


def test_training_bytes_is_a_floor_of_the_measured_cost():
    # Measured: 96 B per sample slot (see trainer.BYTES_PER_SAMPLE_SLOT).
    assert training_bytes(32768 - 1024, 16, 3) < (407176 - 263352) * 1024
    assert training_bytes(2048, 16, 3) == 2 * training_bytes(1024, 16, 3)


def test_sharpness_stays_under_its_rising_cap(scene_xml, tmp_path):
    """s starts at 20 (variance 0.3): the first step under a cap of 8 brings it down to 8, and no
    step leaves it above that step's cap, which rises geometrically to 16 over the run."""
    trainer = new_trainer(scene_xml, tmp_path, sharpness_start=8.0, sharpness_end=16.0)
    cfg = trainer.cfg
    assert [cfg.sharpness_cap(it) for it in (0, cfg.iterations // 2, cfg.iterations, 10 * cfg.iterations)] \
        == pytest.approx([8.0, 8.0 * 2 ** 0.5, 16.0, 16.0])
    for it in range(cfg.iterations):
        trainer.step()
        s = float(trainer.field.inv_s()[0])
        assert s <= cfg.sharpness_cap(it) * (1 + 1e-6)
        if it == 0:
            assert s == pytest.approx(8.0, rel=1e-6)
    with pytest.raises(ReneusError, match=r'train.sharpness_end=32.0: expected at least train.sharpness_start=64.0'):
        TrainConfig(sharpness_start=64.0, sharpness_end=32.0)


def test_sharpness_is_held_at_its_cap_at_the_end(scene_xml, tmp_path):
    """s starts at 20 (variance 0.3), under a cap rising from 30 to 60: learned freely over the
    first half, and from the step at which the hold begins exactly at that step's cap."""
    trainer = new_trainer(scene_xml, tmp_path, sharpness_start=30.0, sharpness_end=60.0, sharpness_hold=0.5,
                          sharpness_floor=1.0)
    cfg = trainer.cfg
    begins = math.ceil(0.5 * cfg.iterations)
    assert cfg.sharpness_min(begins - 1) == 0.0
    assert cfg.sharpness_min(begins) == pytest.approx(cfg.sharpness_cap(begins))
    assert TrainConfig(sharpness_start=30.0, sharpness_floor=0.5).sharpness_min(3000) == pytest.approx(256.0)
    for it in range(cfg.iterations):
        trainer.step()
        s = float(trainer.field.inv_s()[0])
        if it < begins:
            assert s < cfg.sharpness_cap(it)
        else:
            assert s == pytest.approx(cfg.sharpness_cap(it), rel=1e-5)
    with pytest.raises(ReneusError, match=r'train.sharpness_floor=1.5: expected a share in \[0, 1\]'):
        TrainConfig(sharpness_start=30.0, sharpness_floor=1.5)
    with pytest.raises(ReneusError, match=r'train.sharpness_floor=1.0: needs train.sharpness_start'):
        TrainConfig(sharpness_floor=1.0)


def test_rays_through_the_container_edges_are_left_out_of_the_colour_loss(scene_xml, tmp_path):
    """model.render.edge_margin: the flagged rays keep their colour (no loss, no error to draw
    by); a margin wider than the container flags every ray that meets it (the few drawn
    pixels whose ray misses it still count)."""
    colour, drawn_by_error = {}, {}
    for margin in (0.0, 100.0):
        trainer = tiny_run(scene_xml, tmp_path / f'margin_{margin:g}',
                           settings=[f'model.render.edge_margin={margin}']).trainer()
        colour[margin] = trainer.step().terms['color']
        drawn_by_error[margin] = int(np.sum(np.array(trainer.pixels.error) > 0.0))
    assert colour[100.0] < 0.1 * colour[0.0] and drawn_by_error[100.0] < 0.1 * drawn_by_error[0.0]


def test_walls_are_not_searched_without_a_board(tmp_path_factory, tmp_path):
    # In uniform light the empty glass shows that light whatever its walls (Trainer.fit_media):
    # a search would follow the specimen's pixels alone. The field's refinement sees them.
    scene_xml = tiny_dataset(tmp_path_factory.getbasetemp() / 'tiny_case', container='case')
    trainer = new_trainer(scene_xml, tmp_path, **{'refine.wall': True})
    before = trainer.refined_values()['container.wall']
    trainer.fit_media()
    assert trainer.refined_values()['container.wall'] == before
    trainer.search_walls()
    assert trainer.refined_values()['container.wall'] != before
