"""Named configurations: the one registry that the CLIs, the scene writer, the
benchmarks, the tests and the notebooks take their settings from.

======= ==============================================================
preset  what it is for
======= ==============================================================
paper   NeuS's field (256 x 8), 64 + 64 samples: the paper, for a GPU
cpu     a NeuS field sized for a CPU (64 x 4), 32 + 32 samples
demo    the embedded demo: the fast field at the demo's size (6 levels to
        128), 1000 steps of 1024 rays (minutes on a 2-core CPU)
small   a small NeuS field (32 x 4), 32 + 16 samples, 300 steps of 256
        rays: bench/compare.py --config small, the end-to-end test
fast    a hash-grid SDF (7 levels to 256, 2^16 entries) with tiny MLPs and
        an analytic gradient, 24 + 8 samples, a 64^3 occupancy grid that
        skips empty segments, λ1 = 0.01, the sharpness s held below a cap
        that rises from 64 to 512, the reach term, 4096 rays a step: the
        CPU and GPU workhorse
tiny    tests and notebook smoke runs: width 16, 8 + 8 samples, 64 rays
        per step (seconds per run; not for results)
======= ==============================================================

``preset(name)`` returns a fresh copy; change it with
:func:`reneus_mi.utils.settings.replace` (``replace(cfg, **{'train.iterations': 100})``).
"""
from __future__ import annotations

import copy

from reneus_mi.config import ModelConfig, ReconstructionConfig, TrainConfig
from reneus_mi.fields import HashGridFieldConfig, NeuSFieldConfig
from reneus_mi.render.ray_samplers import SamplerConfig
from reneus_mi.utils.errors import ReneusError

#: NeuS's field at CPU size (the small and the cpu preset's architecture differ in width only).
_SMALL_NEUS = dict(layers=4, color_layers=2, multires=4, multires_view=2, init_radius=0.3)
#: The hash-grid presets' sampling and training. λ1 = 0.1 (the paper's L_trans weight) empties a
#: hash grid (docs/constants.md); a free sharpness outruns thin parts (docs/quality.md), and
#: legs not grown yet get their gradient from the reach term (weight and threshold: docs/constants.md).
_GRID_SAMPLER = SamplerConfig(n_coarse=24, n_fine=8, n_upsample_steps=2, occupancy_resolution=64)
_GRID_TRAIN = dict(learning_rate=1e-3, warm_up=50, trans_weight=0.01, sharpness_start=64.0,
                   reach_weight=1.0, reach_threshold=0.1)
#: Rays a step of `fast`: on a 2-core CPU a step of a capture costs some 63 ms whatever its batch
#: (tracing, code generation, launches) and 45 ms per 1,024 rays, so 4,096 rays give 1.8x the
#: rays a second of 1,024, and at 10 minutes the same meshes or better (docs/profile.md,
#: docs/quality.md). The demo keeps 1,024: its 1,000 steps are its length.
_FAST_BATCH = 4096

PRESETS: dict[str, ReconstructionConfig] = {
    'paper': ReconstructionConfig(),
    'cpu': ReconstructionConfig(
        ModelConfig(NeuSFieldConfig(hidden=64, n_features=16, color_hidden=64, **_SMALL_NEUS),
                    SamplerConfig(n_coarse=32, n_fine=32, n_upsample_steps=2)),
        TrainConfig(batch_rays=512, learning_rate=1e-3)),
    'small': ReconstructionConfig(
        ModelConfig(NeuSFieldConfig(hidden=32, n_features=8, color_hidden=32, **_SMALL_NEUS),
                    SamplerConfig(n_coarse=32, n_fine=16, n_upsample_steps=2)),
        TrainConfig(iterations=300, batch_rays=256, learning_rate=2e-3, warm_up=50, validate_every=100,
                    mesh_resolution=128)),
    'fast': ReconstructionConfig(
        ModelConfig(HashGridFieldConfig(init_radius=0.3, n_levels=7, finest_resolution=256), _GRID_SAMPLER),
        TrainConfig(iterations=2000, batch_rays=_FAST_BATCH, validate_every=500, mesh_resolution=256,
                    **_GRID_TRAIN)),
    'demo': ReconstructionConfig(
        ModelConfig(HashGridFieldConfig(init_radius=0.3, n_levels=6, finest_resolution=128), _GRID_SAMPLER),
        TrainConfig(iterations=1000, batch_rays=1024, validate_every=250, mesh_resolution=192, **_GRID_TRAIN)),
    'tiny': ReconstructionConfig(
        ModelConfig(NeuSFieldConfig(hidden=16, layers=2, n_features=8, color_hidden=16, color_layers=1,
                                    multires=2, multires_view=1, init_radius=0.3),
                    SamplerConfig(n_coarse=8, n_fine=8, n_upsample_steps=2)),
        TrainConfig(iterations=6, batch_rays=64, warm_up=2, validate_every=0, checkpoint_every=0,
                    mesh_resolution=16)),
}


def preset(name: str) -> ReconstructionConfig:
    """A fresh copy of the preset ``name``."""
    if name not in PRESETS:
        raise ReneusError(f"preset={name!r}; expected one of {', '.join(PRESETS)}")
    return copy.deepcopy(PRESETS[name])
