"""Every notebook runs top to bottom in a Jupyter kernel (nbclient) at its smoke size, and
shows what its prose says.

RENEUS_NOTEBOOK_SMOKE=1 is the notebooks' one size switch; TMPDIR points their data and runs
at the test's own folder. A cell that raises fails the test (nbclient's CellExecutionError).
After the notebook's cells, one added cell prints the figures the assertions check.
"""
import json
import os

import nbformat
import numpy as np
import pytest
from nbclient import NotebookClient

from reneus_mi.presets import preset

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..'))
NOTEBOOKS = os.path.join(ROOT, 'notebooks')


def run_notebook(name, report, tmp_path, monkeypatch):
    """Execute notebook ``name``, then ``report`` (an expression); return its value (JSON)."""
    monkeypatch.setenv('RENEUS_NOTEBOOK_SMOKE', '1')
    monkeypatch.setenv('TMPDIR', str(tmp_path))
    monkeypatch.setenv('PYTHONPATH', os.pathsep.join(filter(None, [ROOT, os.environ.get('PYTHONPATH')])))
    monkeypatch.setenv('MPLBACKEND', 'Agg')
    nb = nbformat.read(os.path.join(NOTEBOOKS, name), as_version=4)
    nb.cells.append(nbformat.v4.new_code_cell(f'import json as _json\nprint(_json.dumps({report}))'))
    NotebookClient(nb, timeout=600, kernel_name='python3',
                   resources={'metadata': {'path': NOTEBOOKS}}).execute()
    text = ''.join(o.get('text', '') for o in nb.cells[-1].outputs if o.get('name') == 'stdout')
    return json.loads(text.strip().splitlines()[-1])


def test_notebooks_are_committed_without_outputs():
    for name in sorted(os.listdir(NOTEBOOKS)):
        if name.endswith('.ipynb'):
            nb = nbformat.read(os.path.join(NOTEBOOKS, name), as_version=4)
            assert all(not c.get('outputs') for c in nb.cells if c.cell_type == 'code'), name


@pytest.mark.slow
def test_rendering_through_glass(tmp_path, monkeypatch):
    r = run_notebook('01_rendering_through_glass.ipynb',
                     "{'twin_error': twin_error, 'mae': mae, 'eta': eta, 'R_in': R_in[[0, -1]].tolist(), "
                     "'R_out': R_out[[0, -1]].tolist(), 'critical': float(critical)}", tmp_path, monkeypatch)
    # terminal=black at D_re is path with max_depth = D_re + 1: no bias beyond noise and aliasing.
    assert all(abs(e) < 0.03 for e in r['twin_error'].values()), r['twin_error']
    # The ambient truncation is far closer to the converged image than black.
    assert r['mae']['ambient'][2] < 0.5 * r['mae']['black'][2], r['mae']
    eta = r['eta']
    assert r['R_in'][0] == pytest.approx(((eta - 1) / (eta + 1)) ** 2, rel=1e-3)
    assert r['R_out'][-1] == pytest.approx(1.0)  # total internal reflection past the critical angle
    assert r['critical'] == pytest.approx(np.degrees(np.arcsin(1 / eta)))


@pytest.mark.slow
def test_reconstruction(tmp_path, monkeypatch):
    r = run_notebook('02_reconstruction.ipynb',
                     "{'history': history, 'weights': [λ1, λ2], 'preset': PRESET, 'steps': ITERATIONS, "
                     "'changed': float(np.abs(np.asarray(after) - np.asarray(before)).mean()), "
                     "'vertices': len(mesh.vertices), 'chamfer': chamfer(mesh, gt)['chamfer']}",
                     tmp_path, monkeypatch)
    h = r['history']
    train = preset(r['preset']).train
    λ1, λ2 = r['weights']
    assert (λ1, λ2) == (train.trans_weight, train.eikonal_weight)
    assert len(h['loss']) == r['steps'] and np.all(np.isfinite(h['loss']))
    # The loss of Eq. 13 is the weighted sum of its three terms at every step (and the reach
    # term's, where the preset has it).
    np.testing.assert_allclose(h['loss'], np.asarray(h['color']) + λ1 * np.asarray(h['trans'])
                               + λ2 * np.asarray(h['eikonal'])
                               + train.reach_weight * np.asarray(h.get('reach', 0.0)), rtol=1e-5)
    # params.update(opt) wrote into the field that mi.render renders: the image moved.
    assert r['changed'] > 1e-3, r['changed']
    assert r['vertices'] > 0 and np.isfinite(r['chamfer'])


@pytest.mark.slow
def test_evaluation(tmp_path, monkeypatch):
    r = run_notebook('03_evaluation.ipynb',
                     "{'scores': scores, 'accuracy': {k: float(v.mean()) for k, v in accuracy.items()}}",
                     tmp_path, monkeypatch)
    assert set(r['scores']) == {'NeuS', 'ReNeuS'}
    for name, s in r['scores'].items():
        assert s['chamfer'] == pytest.approx(100 * (s['accuracy'] + s['completeness']) / 2)
        assert 0 < s['accuracy'] < 1 and 0 < s['completeness'] < 1
        # The colour map's per-vertex distances measure the same thing as the Chamfer accuracy.
        assert r['accuracy'][name] == pytest.approx(s['accuracy'], rel=0.5)


@pytest.mark.slow
def test_specimen_jar(tmp_path, monkeypatch):
    r = run_notebook('04_specimen_jar.ipynb',
                     "{'count': interfaces.count, 'field': interfaces.field, 'ior': list(interfaces.ior), "
                     "'scores': scores}", tmp_path, monkeypatch)
    # Two interfaces, the field in the liquid, the IORs from the world in: glass, then ethanol.
    assert r['count'] == 2 and r['field'] == 2
    assert r['ior'] == pytest.approx([1.45, 1.36], rel=1e-5)
    assert set(r['scores']) == {'jar', 'solid block'} and all(np.isfinite(list(r['scores'].values())))
