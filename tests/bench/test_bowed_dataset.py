"""bench/bowed_dataset.py's block: closed, its sides and top bulging by the bow at their
centres and not at their edges, its bottom flat on the board."""
import importlib.util
import os

import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location(
    'bowed_dataset', os.path.join(os.path.dirname(__file__), '..', '..', 'bench', 'bowed_dataset.py'))
bowed_dataset = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bowed_dataset)

SIZE = (40.0, 30.0, 22.0)


def test_the_block_bulges_at_its_faces_centres_and_stands_flat():
    mesh = bowed_dataset.bowed_block(SIZE, 0.3)
    assert mesh.is_watertight and mesh.volume > np.prod(SIZE)
    lo, hi = mesh.bounds
    # The sides and the top (up is -z) reach 0.3 mm past the box; the bottom stays on z = 0.
    np.testing.assert_allclose(hi[:2], [20.3, 15.3], atol=1e-9)
    np.testing.assert_allclose(lo, [-20.3, -15.3, -22.3], atol=1e-9)
    assert hi[2] == pytest.approx(0.0, abs=1e-12)
    # The vertical edges stay where the box's were: across them the bulge is 0.
    v = np.abs(mesh.vertices)
    vertical = (v[:, 0] > 20.0 - 1e-9) & (v[:, 1] > 15.0 - 1e-9)
    assert vertical.sum() > 4 * bowed_dataset.SUBDIVISIONS
    np.testing.assert_allclose(v[vertical][:, :2], np.broadcast_to([20.0, 15.0], (vertical.sum(), 2)), atol=1e-9)
