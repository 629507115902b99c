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
