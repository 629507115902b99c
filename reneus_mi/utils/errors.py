"""The library's one exception type, and turning Mitsuba's wrapped errors into one line.

Library code raises :class:`ReneusError` (a ``ValueError``, so callers that
catch ``ValueError`` keep working) with a message that names the file, field
or value and what was expected. Only a command's ``main()`` turns it into
``error: ...`` on stderr and a non-zero exit status (:func:`exit_on_error`).

Errors of the plugins surface wrapped: ``mi.load_file`` puts the XML location
first and a Python traceback before the plugin's message; ``mi.render`` raises
"error while performing a custom differentiable operation" with the plugin's
error as its cause. :func:`user_message` digs the plugin's message out.
"""
from __future__ import annotations

import contextlib
import sys
import warnings

from reneus_mi.utils import interrupt


class ReneusError(ValueError):
    """Bad input or a state the library cannot go on from; the message says which and why."""


class NoSurfaceError(ReneusError):
    """The field has no zero level set where a mesh was asked for."""


def root_cause(e: BaseException) -> BaseException:
    """The innermost exception in ``e``'s chain of causes."""
    seen = set()
    while (e.__cause__ or e.__context__) is not None and id(e) not in seen:
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return e


def user_message(e: BaseException) -> str:
    """The message a user needs, on one line: where (if Mitsuba said) and what."""
    e = root_cause(e)
    lines = [line.strip() for line in str(e).strip().splitlines() if line.strip()]
    if not lines:
        return repr(e)
    if len(lines) <= 2:
        return ': '.join(lines)
    where = lines[0].split(' Traceback (most recent call last):')[0].rstrip(': ')
    return f'{where}: {lines[-1]}'


def one_line(text: str) -> str:
    """``text`` with its line breaks folded, so that a message is one line of stderr."""
    return ' '.join(part.strip() for part in str(text).splitlines() if part.strip())


@contextlib.contextmanager
def exit_on_error(*extra: type[BaseException]):
    """In a ``main()``: end with ``error: ...`` (one line on stderr, exit status 1); warnings on
    the way print as ``warning: ...``, one line each.

    Catches library errors (``ValueError``, so :class:`ReneusError`),
    ``OSError`` (a full disk, a permission denied: ordinary failures of the
    machine) and the ``extra`` types (e.g. ``RuntimeError`` from Mitsuba). A
    ``KeyboardInterrupt`` (where :mod:`reneus_mi.utils.interrupt` has not taken Ctrl-C
    itself), also one that Mitsuba wrapped, ends with its one line and status 130.
    """
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _warning_line
            yield
    except KeyboardInterrupt:
        _interrupted()
    except (ValueError, OSError, *extra) as e:
        if isinstance(root_cause(e), KeyboardInterrupt):
            _interrupted()
        text = user_message(e) if isinstance(e, RuntimeError) else _os_text(e)
        raise SystemExit(f'error: {one_line(text)}') from None


def _warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as a command prints it: ``warning: ...`` on one line of stderr, as errors are
    (not Python's form, with the source file and line that raised it)."""
    print(f'warning: {one_line(message)}', file=sys.stderr)


def _interrupted():
    print(interrupt.message(), file=sys.stderr)
    raise SystemExit(interrupt.STATUS) from None


def _os_text(e: BaseException) -> str:
    if isinstance(e, OSError) and e.filename:
        return f'{e.filename}: {e.strerror or e}'
    return str(e)
