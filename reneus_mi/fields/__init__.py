"""Fields: what lives inside the container (SDF + radiance + sharpness)."""
from reneus_mi.fields.analytic import BoxField, SphereField, TorusField
from reneus_mi.fields.base import Field, load_field
from reneus_mi.fields.hashgrid import HashGridField
from reneus_mi.fields.neus import NeuSField

FIELD_KINDS = {cls.__name__: cls for cls in (SphereField, BoxField, TorusField, NeuSField,
                                             HashGridField)}

__all__ = ['Field', 'SphereField', 'BoxField', 'TorusField', 'NeuSField', 'HashGridField', 'load_field', 'FIELD_KINDS']
