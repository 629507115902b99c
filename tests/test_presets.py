"""Every preset loads in a scene and renders."""
import dataclasses

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from reneus_mi.presets import PRESETS
from reference import glass_scene

#: Field settings rendered in place of a preset's own. LLVM takes about 7 minutes (406 s,
#: 2-core CPU, cold kernel cache) to compile one evaluation of the paper's 256 x 8 MLP (a GPU
#: preset): its sampler and render settings are rendered here with the cpu preset's widths, and
#: its field is built at full size.
NARROWER = {'paper': {'field_hidden': 64, 'field_n_features': 16, 'field_color_hidden': 64}}


@pytest.mark.parametrize('name', sorted(PRESETS))
def test_each_preset_loads_and_renders(name):
    narrower = NARROWER.get(name, {})
    scene = glass_scene(preset=name, **narrower)
    model = scene.integrator().model
    given = {key.removeprefix('field_'): value for key, value in narrower.items()}
    assert model == dataclasses.replace(PRESETS[name].model,
                                        field=dataclasses.replace(PRESETS[name].model.field, **given))
    if narrower:    # built at its own size: its networks, and the sharpness s
        full = PRESETS[name].model.field
        assert sum(dr.width(v) for v in full.setup().params().values()) == full.parameters() + 1
    image = np.array(mi.render(scene, spp=1))
    assert image.shape == (3, 3, 3) and np.all(np.isfinite(image)) and image.min() >= 0
