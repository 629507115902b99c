"""Turning exceptions from inside Mitsuba/Dr.Jit into one readable message.

Errors of the plugins surface wrapped: ``mi.load_file`` puts the XML location
first and a Python traceback before the plugin's message; ``mi.render`` raises
"error while performing a custom differentiable operation" with the plugin's
error as its cause. Command-line tools print :func:`user_message` instead of a
traceback.
"""
from __future__ import annotations


def root_cause(e: BaseException) -> BaseException:
    """The innermost exception in ``e``'s chain of causes."""
    seen = set()
    while (e.__cause__ or e.__context__) is not None and id(e) not in seen:
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return e


def user_message(e: BaseException) -> str:
    """The message a user needs: where (if Mitsuba said) and what."""
    e = root_cause(e)
    lines = [line for line in str(e).strip().splitlines() if line.strip()]
    if not lines:
        return repr(e)
    if len(lines) <= 2:
        return '\n'.join(lines)
    where = lines[0].split(' Traceback (most recent call last):')[0]
    return f'{where}\n  {lines[-1].strip()}'


class ReneusError(ValueError):
    """A problem with the user's input or settings, stated in one line; CLIs print it as is."""


class NoSurfaceError(ReneusError):
    """The field has no zero level set where a mesh was asked for."""


def _owner(obj) -> str:
    return getattr(obj, 'kind', None) or type(obj).__name__


def check_numbers(obj, *, positive=(), at_least_zero=(), finite=()) -> None:
    """One-line errors for numeric fields of a config dataclass out of range or of the wrong type."""
    import math
    import typing
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
