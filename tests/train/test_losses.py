"""The loss dictionary: every term by name and weight, summed by the step and logged."""
from __future__ import annotations

import json

import numpy as np
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


def test_a_pair_of_rays_is_logged_as_the_pixels_mean_error(scene_xml, tmp_path):
    """Paired rays, half the colour loss (``train.pixels.paired``): the step sums and logs it as with one
    ray, the PSNR finite."""
    from reneus_mi.train.pixel_sampler import PixelSamplerConfig
    trainer = new_trainer(scene_xml, tmp_path, iterations=2, pixels=PixelSamplerConfig(paired=0.5))
    trainer.run(progress=False)
    cfg = trainer.cfg
    for line in (tmp_path / 'log.jsonl').read_text().splitlines():
        e = json.loads(line)
        assert e['loss'] == pytest.approx(e['color'] + cfg.trans_weight * e['trans'] + cfg.eikonal_weight
                                          * e['eikonal'] + cfg.reach_weight * e.get('reach', 0.0), rel=1e-5)
        assert 0 < e['color'] < 1


def _edge_loss_gradient(loss, sharpness: float, pixels: int = 1 << 16, seed: int = 0):
    """A pixel half covered by a bright leg on a dark background (photograph: 0.5) and a field
    that draws the leg's edge at the pixel's middle, blurred over 1 / ``sharpness`` pixels:
    the loss of rays through random points x of many such pixels, and its derivative in the
    sharpness."""
    import drjit as dr
    import mitsuba as mi
    rng = np.random.default_rng(seed)
    s = mi.Float(sharpness)
    dr.enable_grad(s)

    def ray():
        x = mi.Float(rng.random(pixels).astype(np.float32))
        return mi.Color3f(dr.rcp(1.0 + dr.exp(s * (x - 0.5))))
    value = loss(ray, mi.Color3f(0.5))
    dr.backward(value)
    return value[0], dr.grad(s)[0]


def test_one_ray_a_pixel_prefers_the_blur_and_a_pair_does_not():
    """The pixel's mean is the photograph's at every sharpness (the edge at its middle), so the
    pixel's mean error has no gradient in it. One ray's L1 grows with the sharpness (a sharp
    edge errs by half the contrast on every ray; its gradient pulls the field to the blur);
    the pair's gradient is zero within its noise."""
    from reneus_mi.train.losses import color_l1, paired_l1
    one, one_grad = _edge_loss_gradient(lambda ray, t: color_l1(ray(), t), 4.0)
    _, pair_grad = _edge_loss_gradient(lambda ray, t: paired_l1(ray(), ray(), t), 4.0)
    assert one > 0.1 and one_grad > 0.01
    assert abs(pair_grad) < 0.05 * one_grad


def test_a_pair_that_agrees_has_l1s_value_and_gradient():
    """Two rays of the same colour: the pair's loss and its gradient are L1's of that colour."""
    import drjit as dr
    import mitsuba as mi
    from reneus_mi.train.losses import color_l1, paired_l1
    target = mi.Color3f([0.2, 0.7], [0.4, 0.1], [0.9, 0.5])
    grads = []
    for loss in (lambda c: color_l1(c, target), lambda c: paired_l1(c, c, target)):
        c = mi.Color3f([0.5, 0.6], [0.3, 0.3], [0.1, 0.55])
        dr.enable_grad(c)
        value = loss(c)
        dr.backward(value)
        grads.append((value[0], np.asarray(dr.grad(c))))
    assert grads[1][0] == pytest.approx(grads[0][0], rel=1e-5)
    assert np.allclose(grads[1][1], grads[0][1], atol=1e-5)
