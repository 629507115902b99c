"""The ``reneus`` integrator's XML properties, read into the configuration and written back.

Every property is a field of :class:`~reneus_mi.render.config.ModelConfig` under the same name
(``max_depth`` is ``model.render.max_depth``, ``n_coarse`` is ``model.sampler.n_coarse``,
``field_hidden`` is ``model.field.hidden``), over the named ``preset``; a few more say where
the field lives and what it is fitted to (:data:`OTHER`). :func:`read_properties` reads them
as the plugin is built, :func:`xml_properties` writes settings as such properties (the scene
writer), so the two directions are one mapping.
"""
from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass

import mitsuba as mi

from reneus_mi.fields import FIELD_CONFIGS, Field, FieldConfig, load_field
from reneus_mi.geometry.frame import FieldFrame
from reneus_mi.presets import preset
from reneus_mi.render.config import ModelConfig, RenderConfig
from reneus_mi.render.ray_samplers import SamplerConfig
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.settings import typed_value

#: Properties that are not settings of the model.
OTHER = ('preset', 'field', 'field_center', 'field_scale', 'dataset')
#: The preset of an integrator that names none.
DEFAULT_PRESET = 'paper'
#: The model's sections that take properties by their fields' own names.
_SECTIONS = (('render', RenderConfig), ('sampler', SamplerConfig))


@dataclass
class IntegratorProperties:
    """What an ``<integrator type="reneus">`` element says."""
    preset: str
    """The named configuration the other properties override."""
    model: ModelConfig
    """The model rendered: the preset's, with the properties given."""
    field: Field | None
    """A saved field that ``field`` names (None: a fresh one is built from ``model.field``)."""
    frame: FieldFrame
    """Where the field's unit sphere lies in the world (the container's bounds come with the scene)."""
    dataset: str
    """The folder of photographs that ``reneus_mi.optimize`` fits the field to ('' for none)."""


def read_properties(props: mi.Properties) -> IntegratorProperties:
    """The integrator's XML properties, checked: every error names the property and what was expected."""
    name = _get(props, 'preset', str, DEFAULT_PRESET)
    try:
        model = preset(name).model
    except ReneusError as e:
        raise ReneusError(f'reneus integrator: {e}') from None
    sections = {}
    for section, cls in _SECTIONS:
        hints = typing.get_type_hints(cls)
        given = {f.name: _get(props, f.name, hints[f.name]) for f in dataclasses.fields(cls)
                 if f.name in props}
        sections[section] = _build(cls, getattr(model, section), given)
    field, field_cfg = _read_field(props, model)
    center = _get(props, 'field_center', tuple, (0.0, 0.0, 0.0))
    frame = FieldFrame(center=center, scale=_get(props, 'field_scale', float, 1.0))
    dataset = _get(props, 'dataset', str, '')
    unknown = list(props.unqueried())
    if unknown:
        known = [f.name for _, c in _SECTIONS for f in dataclasses.fields(c)]
        raise ReneusError(f"reneus integrator: unknown parameter(s) {', '.join(map(repr, unknown))}; "
                          f"expected {', '.join(known + list(OTHER))} or field_<name>")
    return IntegratorProperties(name, ModelConfig(field=field_cfg, **sections), field, frame, dataset)


def _read_field(props: mi.Properties, model: ModelConfig):
    """(saved field or None, its configuration) of ``field`` and the ``field_<name>`` properties."""
    spec = _get(props, 'field', str, model.field.kind)
    field_props = {n[len('field_'):]: n for n in props.keys()
                   if n.startswith('field_') and n not in OTHER}
    if spec.endswith('.npz'):
        if field_props:
            raise ReneusError(f'reneus integrator: field={spec!r} is a saved field; '
                              f"field_* parameters ({', '.join(field_props.values())}) do not apply")
        field = load_field(spec)
        return field, field.Config(**field.config())
    if spec not in FIELD_CONFIGS:
        raise ReneusError(f"reneus integrator: field={spec!r}; expected one of "
                          f"{', '.join(FIELD_CONFIGS)} or the path of a saved field (.npz)")
    cls = FieldConfig.of_kind(spec, 'field')
    base = model.field if model.field.kind == spec else cls()
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(field_props) - known)
    if unknown:
        raise ReneusError(f"reneus integrator: unknown parameter(s) "
                          f"{', '.join(repr(field_props[u]) for u in unknown)}; the {spec} field "
                          f"takes field_<name> for name in {', '.join(sorted(known))}")
    return None, _build(cls, base, {k: _get(props, n, hints[k]) for k, n in field_props.items()})


def xml_properties(settings: dict) -> dict:
    """The integrator's XML properties of model settings given by dotted path, as
    :func:`read_properties` reads them back: ``model.render.max_depth`` -> ``max_depth``,
    ``model.sampler.n_coarse`` -> ``n_coarse``, ``model.field.hidden`` -> ``field_hidden``,
    ``model.field`` (a field configuration) -> ``field`` (its kind)."""
    out = {}
    sections = [section for section, _ in _SECTIONS]
    for path, value in settings.items():
        parts = path.split('.')
        if parts[:2] == ['model', 'field'] and len(parts) <= 3:
            out['field_' + parts[2] if len(parts) == 3 else 'field'] = value if len(parts) == 3 else value.kind
        elif parts[0] == 'model' and len(parts) == 3 and parts[1] in sections:
            out[parts[2]] = value
        else:
            raise ReneusError(f'{path}: not a setting of the reneus integrator (its scene holds '
                              'model.render.*, model.sampler.* and model.field.*; train.* are '
                              "optimize's)")
    return out


def _get(props: mi.Properties, name: str, kind, default=None):
    """Property ``name`` checked against ``kind``; the error names it and what was expected."""
    if name not in props:
        return default
    value = props.get(name)
    if kind is tuple or typing.get_origin(kind) is tuple:
        value = tuple(float(v) for v in value) if not isinstance(value, (str, bool, int, float)) else value
    try:
        return typed_value(value, kind, f'reneus integrator: {name}')
    except ReneusError as e:
        raise ReneusError(str(e)) from None


def _build(cls, base, given: dict):
    """``base`` (a config of ``cls``) with the ``given`` fields, validated."""
    try:
        return dataclasses.replace(base, **given)
    except ReneusError as e:
        raise ReneusError(f'reneus integrator: {e}') from None
