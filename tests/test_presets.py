"""Every preset loads in a scene and renders."""
import mitsuba as mi
import numpy as np
import pytest

from reneus_mi.presets import PRESETS
from reference import glass_scene


@pytest.mark.parametrize('name', sorted(PRESETS))
def test_each_preset_loads_and_renders(name):
    scene = glass_scene(preset=name)
    it = scene.integrator()
    assert it.model == PRESETS[name].model
    image = np.array(mi.render(scene, spp=1))
    assert image.shape == (3, 3, 3) and np.all(np.isfinite(image)) and image.min() >= 0
