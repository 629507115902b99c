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
