"""One-line errors for the fields of configuration dataclasses out of range, called from
their ``__post_init__``."""
from __future__ import annotations

import math
import typing

from reneus_mi.utils.errors import ReneusError


def _owner(obj) -> str:
    return getattr(obj, 'kind', None) or type(obj).__name__


def check_numbers(obj, *, positive=(), at_least_zero=(), finite=()) -> None:
    """One-line errors for numeric fields of a config dataclass out of range or of the wrong type."""
    hints = typing.get_type_hints(type(obj))
    for names, test, expected in ((positive, lambda v: v > 0, '> 0'),
                                  (at_least_zero, lambda v: v >= 0, '>= 0'),
                                  (finite, lambda v: True, '(finite)')):
        for name in names:
            value, kind = getattr(obj, name), hints[name]
            typed = isinstance(value, int) if kind is int else isinstance(value, (int, float))
            if not typed or isinstance(value, bool) or not math.isfinite(value) or not test(value):
                what = 'an integer' if kind is int else 'a number'
                raise ReneusError(f'{_owner(obj)}: {name}={value!r}; expected {what} {expected}')


def check_choice(obj, name: str, choices) -> None:
    """One-line error unless the field ``name`` of ``obj`` is one of ``choices``."""
    value = getattr(obj, name)
    if value not in choices:
        raise ReneusError(f"{_owner(obj)}: {name}={value!r}; expected one of {', '.join(map(repr, choices))}")
