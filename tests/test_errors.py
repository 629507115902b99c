"""Errors end a command with one line naming the thing, never a traceback."""
import pytest

from reneus_mi.utils.errors import ReneusError, exit_on_error, user_message


def test_exit_on_error_is_one_line():
    with pytest.raises(SystemExit) as e:
        with exit_on_error():
            raise ReneusError('a\nb')
    assert e.value.code == 'error: a b'
    with pytest.raises(SystemExit) as e:
        with exit_on_error():
            open('/nonexistent/x')
    assert e.value.code == "error: /nonexistent/x: No such file or directory"
    wrapped = RuntimeError('scene.xml (line 3): Traceback (most recent call last):\n  x\nValueError: bad')
    assert user_message(wrapped) == 'scene.xml (line 3): ValueError: bad'
