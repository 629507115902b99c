"""The preview of a mesh: framed to fill the picture, lit as stated (clay 0.6 under an
ambient of 0.25 and a key light of irradiance 2)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from reneus_mi.render.preview import FOV, MARGIN, render_preview
from reneus_mi.utils.errors import ReneusError


def _linear(png):
    from PIL import Image
    c = np.asarray(Image.open(png).convert('RGB'), np.float64).mean(axis=2) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def test_preview_of_a_sphere(tmp_path):
    mesh = tmp_path / 'sphere.ply'
    trimesh.creation.icosphere(subdivisions=5, radius=0.3).apply_translation([1.0, 2.0, 3.0]).export(mesh)
    size = 128
    image = _linear(render_preview(str(mesh), str(tmp_path / 'p.png'), size=size, spp=512))
    background = np.abs(image - 0.25) < 0.01
    assert background[0, 0] and background.mean() > 0.3
    # The bounding sphere fills the frame: the sphere's outline's radius in pixels.
    r, fov = 0.3 * np.sqrt(3.0), np.radians(FOV / 2)
    distance = r / np.sin(fov) * MARGIN
    expected = np.tan(np.arcsin(0.3 / distance)) / np.tan(fov) * size / 2
    area = (~background).sum()
    assert np.sqrt(area / np.pi) == pytest.approx(expected, rel=0.03)
    # Lambertian clay: ambient alone where the key light does not reach, 0.6 (0.25 + 2 / pi)
    # where it falls straight on.
    inside = image[~background]
    assert np.percentile(inside, 99.5) == pytest.approx(0.6 * (0.25 + 2.0 / np.pi), rel=0.03)
    assert np.percentile(inside, 0.5) == pytest.approx(0.6 * 0.25, rel=0.05)


def test_preview_refusals(tmp_path):
    trimesh.Trimesh().export(tmp_path / 'empty.ply')
    with pytest.raises(ReneusError, match='holds no triangles'):
        render_preview(str(tmp_path / 'empty.ply'), str(tmp_path / 'p.png'))
    trimesh.creation.box().export(tmp_path / 'box.ply')
    with pytest.raises(ReneusError, match='lies along the view direction'):
        render_preview(str(tmp_path / 'box.ply'), str(tmp_path / 'p.png'), direction=(0, 0, 2), up=(0, 0, 1))
