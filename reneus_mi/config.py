"""The settings of a reconstruction, as nested dataclasses.

A :class:`ReconstructionConfig` is what a run is made of::

    ReconstructionConfig
    ├── model: ModelConfig          what is rendered (the scene's <integrator type="reneus">)
    │   ├── field: NeuSFieldConfig | HashGridFieldConfig | SphereFieldConfig | ...
    │   ├── sampler: SamplerConfig  samples per inside segment (reneus_mi.render.ray_samplers)
    │   └── render: RenderConfig    mode, D_re, terminal, gamma
    └── train: TrainConfig          how it is fitted (reneus_mi.optimize)
        └── refine: RefineConfig    beyond the paper: the container's IOR and pose, the light

Each part is defined in the layer it configures (the model in :mod:`reneus_mi.render.config`,
the training in :mod:`reneus_mi.train.config`, the fields beside their classes); this module
puts them together. Every field has its default written once, and a docstring (the string
literal under it) that is its documentation and its command-line help.
:mod:`reneus_mi.presets` names complete configurations (``paper``, ``cpu``, ``demo``,
``fast``). :func:`to_dict` and :func:`from_dict` (:mod:`reneus_mi.utils.settings`) turn a
configuration into JSON and back (a run's ``config.json``), with an error naming any unknown
or mistyped key.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from reneus_mi.render.config import MODES, TERMINALS, ModelConfig, RenderConfig
from reneus_mi.train.config import RefineConfig, TrainConfig
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.settings import from_dict, parse_setting, replace, setting_type, to_dict, with_settings

__all__ = ['MODES', 'TERMINALS', 'ModelConfig', 'RenderConfig', 'RefineConfig', 'TrainConfig',
           'ReconstructionConfig', 'from_dict', 'parse_setting', 'replace', 'setting_type', 'to_dict',
           'with_settings']


@dataclass
class ReconstructionConfig:
    """A whole reconstruction: the model that is rendered and how it is trained."""

    model: ModelConfig = dataclasses.field(default_factory=ModelConfig)
    """What is rendered."""
    train: TrainConfig = dataclasses.field(default_factory=TrainConfig)
    """How it is fitted."""

    def __post_init__(self):
        if self.train.refine.any() and self.model.render.mode == 'neus':
            raise ReneusError('train.refine (ior, absorption, pose, light) needs a container: mode is neus')
