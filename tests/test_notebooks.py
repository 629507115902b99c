"""The notebooks run top to bottom (at their small settings) and do what they say."""
import json
import os

import numpy as np
import pytest

NOTEBOOKS = os.path.join(os.path.dirname(__file__), '..', 'notebooks')


def run_notebook(name, **overrides):
    with open(os.path.join(NOTEBOOKS, name)) as f:
        cells = [''.join(c['source']) for c in json.load(f)['cells'] if c['cell_type'] == 'code']
    namespace = {}
    for i, source in enumerate(cells):
        exec(compile(source, f'{name}[cell {i}]', 'exec'), namespace)
        if i == 0:
            namespace.update(overrides)
    return namespace


@pytest.mark.slow
def test_glass_sphere_notebook_fits_the_photographs():
    ns = run_notebook('glass_sphere_inverse_rendering.ipynb', ITERATIONS=40)
    losses = ns['losses']
    assert np.mean(losses[-ns['VIEWS']:]) < 0.8 * np.mean(losses[:ns['VIEWS']])
    assert len(ns['mesh'].vertices) > 100
