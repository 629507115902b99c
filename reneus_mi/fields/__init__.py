"""Fields: what lives inside the container (SDF + radiance + sharpness).

Each kind of field has a configuration dataclass (its ``Config``) whose
``kind`` is the name that scene XML (``<string name="field" value="neus"/>``),
presets and ``config.json`` use.
"""
from reneus_mi.fields.analytic import BoxField, SphereField, TorusField
from reneus_mi.fields.base import Field, FieldConfig, load_field
from reneus_mi.fields.hashgrid import HashGridField, HashGridFieldConfig
from reneus_mi.fields.neus import NeuSField, NeuSFieldConfig

#: Field class of each kind.
FIELDS = {cls.Config.kind: cls for cls in (NeuSField, HashGridField, SphereField, BoxField, TorusField)}
#: Configuration dataclass of each kind.
FIELD_CONFIGS = {kind: cls.Config for kind, cls in FIELDS.items()}
#: Field classes by class name, as field files record them.
FIELD_KINDS = {cls.__name__: cls for cls in FIELDS.values()}

__all__ = ['Field', 'FieldConfig', 'SphereField', 'BoxField', 'TorusField', 'NeuSField', 'NeuSFieldConfig',
           'HashGridField', 'HashGridFieldConfig', 'load_field', 'FIELDS', 'FIELD_CONFIGS', 'FIELD_KINDS']
