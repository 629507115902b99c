"""The package's one mesh reader."""
import numpy as np
import pytest
import trimesh

from reneus_mi.geometry.mesh import load_mesh


def test_load_mesh_rejects_a_point_cloud(tmp_path):
    path = tmp_path / 'cloud.ply'
    trimesh.PointCloud(np.random.default_rng(0).random((10, 3))).export(path)
    with pytest.raises(ValueError, match='cloud.ply'):
        load_mesh(path)
