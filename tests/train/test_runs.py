"""Runs: config.json rebuilds a run, a collection skips finished runs and resumes killed ones,
a moved dataset is checked."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

from reneus_mi import runs
from tiny import tiny_run, tiny_spec


def test_config_json_rebuilds_the_same_run(scene_xml, tmp_path):
    first = tiny_run(scene_xml, tmp_path / 'a', iterations=3).train(progress=False)
    spec = runs.read_spec(str(tmp_path / 'a'))
    assert spec.same_run(tiny_spec(scene_xml, iterations=3)) and spec.data_fingerprint['views'] == 12
    again = runs.run_many({'b': spec}, str(tmp_path))['b']
    assert first['iterations'] == again['iterations'] == 3

    def losses(folder):
        with open(tmp_path / folder / 'log.jsonl') as f:
            return [json.loads(line)['loss'] for line in f]
    # Same seed, same settings: the same losses (up to parallel float sums).
    assert np.allclose(losses('a'), losses('b'), rtol=1e-4)
    # Another seed draws other rays.
    spec.config.train.seed = 1
    runs.run_many({'c': spec}, str(tmp_path))
    assert not np.allclose(losses('a'), losses('c'), rtol=1e-2)


def test_run_many_skips_finished_runs_and_refuses_changed_ones(scene_xml, tmp_path):
    specs = {'one': tiny_spec(scene_xml, iterations=2)}
    first = runs.run_many(specs, str(tmp_path))
    mtime = os.path.getmtime(tmp_path / 'one' / 'checkpoint.npz')
    assert runs.run_many(specs, str(tmp_path)) == first
    assert os.path.getmtime(tmp_path / 'one' / 'checkpoint.npz') == mtime
    with pytest.raises(ValueError, match='holds a run with other settings'):
        runs.run_many({'one': tiny_spec(scene_xml, iterations=3)}, str(tmp_path))


def test_resume_on_a_moved_dataset_is_checked(scene_xml, tmp_path):
    import shutil
    from reneus_mi import optimize
    data = os.path.join(os.path.dirname(scene_xml), 'box')
    out = tmp_path / 'run'
    tiny_run(scene_xml, out, iterations=2).train(progress=False)
    moved = tmp_path / 'moved'
    shutil.copytree(data, moved)
    assert runs.prepare(str(out), data=str(moved), start='resume').spec.data == str(moved)
    other = tmp_path / 'other'
    shutil.copytree(data, other)
    meta = json.loads((other / 'transforms.json').read_text())
    meta['frames'] = meta['frames'][:-1]
    (other / 'transforms.json').write_text(json.dumps(meta))
    with pytest.raises(SystemExit, match='not the dataset this run was started on'):
        optimize.main(['-o', str(out), '--resume', '--data', str(other), '--iterations', '3', '--quiet'])
