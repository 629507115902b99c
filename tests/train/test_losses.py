"""The loss dictionary: every term by name and weight, summed by the step and logged."""
from __future__ import annotations

import json

import pytest

from tiny import new_trainer


def test_the_step_sums_and_logs_every_term_by_name(scene_xml, tmp_path):
    """Eq. 13 and the silhouette term (a pose refined on segmented masks): each term is logged
    by its name, and the loss is their weighted sum."""
    trainer = new_trainer(scene_xml, tmp_path, iterations=2, **{'refine.pose': True, 'refine.after': 0})
    assert trainer.silhouette is not None
    trainer.run(progress=False)
    cfg = trainer.cfg
    for line in (tmp_path / 'log.jsonl').read_text().splitlines():
        e = json.loads(line)
        assert e['loss'] == pytest.approx(e['color'] + cfg.trans_weight * e['trans'] + cfg.eikonal_weight
                                          * e['eikonal'] + cfg.refine.silhouette_weight * e['silhouette'],
                                          rel=1e-5)
        assert e['silhouette'] > 0


def test_the_reach_term_is_summed_and_logged_with_several_rays_a_pixel(scene_xml, tmp_path):
    """The reach term's inputs are taken per pixel, as the colour is, when a pixel has four rays."""
    from reneus_mi.train.pixel_sampler import PixelSamplerConfig
    trainer = new_trainer(scene_xml, tmp_path, iterations=2, reach_weight=1.0,
                          pixels=PixelSamplerConfig(rays_per_pixel=4))
    trainer.run(progress=False)
    cfg = trainer.cfg
    for line in (tmp_path / 'log.jsonl').read_text().splitlines():
        e = json.loads(line)
        assert e['loss'] == pytest.approx(e['color'] + cfg.trans_weight * e['trans'] + cfg.eikonal_weight
                                          * e['eikonal'] + e['reach'], rel=1e-5)


def test_reach_pulls_only_where_a_surface_would_bring_the_pixel_nearer_its_photograph():
    """Rays: a dark leg missed on a bright board (pulls by its misfit less the threshold), the
    same within the threshold (no pull), a pixel the field's dark colour would move away from
    its bright photograph (no pull)."""
    import drjit as dr
    import mitsuba as mi
    from types import SimpleNamespace
    from reneus_mi.train.losses import reach
    pixel = mi.Color3f([0.8, 0.8, 0.3], [0.8, 0.8, 0.3], [0.8, 0.8, 0.3])
    target = mi.Color3f([0.3, 0.78, 0.6], [0.3, 0.78, 0.6], [0.3, 0.78, 0.6])
    nearest_color = mi.Color3f(0.2)
    nearest = mi.Float([0.02, 0.02, 0.02])
    dr.enable_grad(nearest)
    value = reach(SimpleNamespace(color=pixel, nearest_color=nearest_color, nearest=nearest), target, 0.05)
    dr.backward(value)
    assert dr.grad(nearest).numpy() == pytest.approx([(0.5 - 0.05) / 3, 0.0, 0.0])
    assert value[0] == pytest.approx(0.02 * 0.45 / 3)
