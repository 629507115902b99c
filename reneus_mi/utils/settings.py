"""Settings as nested dataclasses: to a dict and back, typed from text, replaced by path.

The machinery every configuration shares, whoever owns it (the field's, the renderer's, the
training's, a capture's): a field's type is its check (int, float, str, bool, a tuple of
numbers, a nested dataclass), and every error names the setting's dotted path. A setting whose
type is a family of dataclasses (a field's configuration: ``model.field``) names its member by
``kind``: the family's class has a classmethod ``of_kind(name, where)`` that returns it.
"""
from __future__ import annotations

import dataclasses
import typing

from reneus_mi.utils.errors import ReneusError


def to_dict(cfg) -> dict:
    """Nested plain dict of a config (a member of a family records its ``kind``)."""
    out = {}
    if getattr(cfg, 'kind', None):
        out['kind'] = cfg.kind
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        out[f.name] = to_dict(value) if dataclasses.is_dataclass(value) else \
            (list(value) if isinstance(value, tuple) else value)
    return out


def from_dict(cls, values: dict, where: str = ''):
    """Rebuild ``cls`` from :func:`to_dict`'s output; unknown keys are errors naming their path.

    A key left out keeps its default, so old files stay readable when a setting is added.
    """
    if not isinstance(values, dict):
        raise ReneusError(f'{where or cls.__name__}: expected a mapping of settings, got {values!r}')
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in values.items():
        path = f'{where}.{key}' if where else key
        if key == 'kind' and getattr(cls, 'kind', None):
            continue
        if key not in known:
            raise ReneusError(f"{path}: unknown setting; expected one of {', '.join(known)}")
        kind = hints[key]
        if _is_family(kind):
            kwargs[key] = from_dict(kind.of_kind(value.get('kind') if isinstance(value, dict) else None, path),
                                    value, path)
        elif isinstance(kind, type) and dataclasses.is_dataclass(kind):
            kwargs[key] = from_dict(kind, value, path)
        else:
            kwargs[key] = typed_value(value, kind, path)
    try:
        return cls(**kwargs)
    except ReneusError as e:
        raise ReneusError(f'{where}: {e}' if where else str(e)) from None


def _is_family(kind) -> bool:
    return isinstance(kind, type) and hasattr(kind, 'of_kind')


def typed_value(value, kind, path: str):
    """``value`` checked against a field's type (int, float, str, bool, tuple of floats)."""
    origin = typing.get_origin(kind)
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif kind is str:
        ok = isinstance(value, str)
    elif origin is tuple or kind is tuple:
        ok = isinstance(value, (list, tuple)) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        value = tuple(float(v) for v in value) if ok else value
    else:
        ok = True
    if not ok:
        name = {bool: 'true or false', int: 'an integer', float: 'a number', str: 'a string'}.get(
            kind, 'a list of numbers')
        raise ReneusError(f'{path}={value!r}: expected {name}')
    return value


def text_value(text: str, kind, path: str):
    """A setting given as text (a command line) as a value of ``kind``: an int, float, str,
    ``true``/``false``, numbers separated by commas for a tuple, a member's name for a family
    (its defaults); checked by :func:`typed_value`."""
    if _is_family(kind):
        return kind.of_kind(text, path)()
    value = text
    try:
        if kind is bool:
            value = {'true': True, 'false': False}.get(text.lower(), text)
        elif kind in (int, float):
            value = kind(text)
        elif typing.get_origin(kind) is tuple or kind is tuple:
            value = [float(v) for v in text.split(',')]
    except ValueError:
        pass  # typed_value names what was expected
    return typed_value(value, kind, path)


def setting_type(cfg, path: str):
    """The type that ``cfg`` declares for the dotted ``path`` (``model.sampler.n_coarse``: int;
    under ``model.field`` the fields of the configuration's own field kind)."""
    node, kind, done = cfg, None, []
    for name in path.split('.'):
        if not dataclasses.is_dataclass(node):
            raise ReneusError(f"{path}: {'.'.join(done)} is a value, not a group of settings")
        known = [f.name for f in dataclasses.fields(node)]
        if name not in known:
            where = '.'.join(done) or 'the configuration'
            raise ReneusError(f"{path}: not a setting; {where} has {', '.join(known)}")
        kind, node = typing.get_type_hints(type(node))[name], getattr(node, name)
        done.append(name)
    return kind


def parse_setting(cfg, text: str) -> tuple[str, object]:
    """``'model.sampler.n_coarse=32'`` as ``('model.sampler.n_coarse', 32)``, typed as ``cfg``
    declares it: the one reader of settings given as text (``--set`` of scene, optimize and
    the benchmarks)."""
    path, sep, value = text.partition('=')
    if not sep or not path:
        raise ReneusError(f'{text!r}: expected PATH=VALUE (e.g. model.sampler.n_coarse=32)')
    return path, text_value(value, setting_type(cfg, path), path)


def with_settings(cfg, texts) -> tuple[object, dict]:
    """``cfg`` with the settings ``texts`` (``PATH=VALUE`` each, in order: ``model.field=hashgrid``
    before the new field's own settings), each checked; and the changes by path."""
    changes = {}
    for text in texts:
        path, value = parse_setting(cfg, text)
        cfg = replace(cfg, **{path: value})
        changes[path] = value
    return cfg, changes


def replace(cfg, **changes):
    """``dataclasses.replace`` for nested configs: keys may be dotted paths (``train.iterations``)."""
    nested: dict[str, dict] = {}
    flat = {}
    for key, value in changes.items():
        head, _, rest = key.partition('.')
        if rest:
            nested.setdefault(head, {})[rest] = value
        else:
            flat[key] = value
    for head, sub in nested.items():
        flat[head] = replace(getattr(cfg, head), **sub)
    return dataclasses.replace(cfg, **flat)
