"""Fields: what lives inside the container (SDF + radiance + sharpness)."""
from reneus_mi.fields.analytic import BoxField, SphereField, TorusField
from reneus_mi.fields.base import Field, load_field

FIELD_KINDS = {cls.__name__: cls for cls in (SphereField, BoxField, TorusField)}

__all__ = ['Field', 'SphereField', 'BoxField', 'TorusField', 'load_field', 'FIELD_KINDS']
