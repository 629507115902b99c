"""Command-line options from a configuration dataclass.

Each field of the dataclass becomes ``--field-name``; the string literal that
follows the field in the class body (its docstring) becomes the help text, so
the documentation lives in one place. Values are typed by
:func:`reneus_mi.utils.settings.text_value`, as every setting given as text is.
"""
from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import textwrap
import typing

from reneus_mi.utils.settings import text_value
from reneus_mi.utils.errors import ReneusError


def field_docs(cls) -> dict[str, str]:
    """Map each field of ``cls`` to the docstring written below it."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body
    docs = {}
    for node, following in zip(body, body[1:]):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                and isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant)
                and isinstance(following.value.value, str)):
            docs[node.target.id] = ' '.join(following.value.value.split())
    return docs


def add_arguments(parser: argparse.ArgumentParser, cls, *, default_note: str | None = None,
                  prefix: str = '', title: str | None = None, as_text: bool = False) -> None:
    """Add one option per field of ``cls``, its docstring as help, the default said once.

    A nested configuration adds its fields under its name: ``TrainConfig.refine.ior``
    is ``--refine-ior``. ``default_note`` replaces the default in the help where
    another source (e.g. a preset) provides it. An option not given is None, so that what was
    given can be told from the defaults (:func:`given_arguments`). ``as_text``: each option
    keeps its text, for the caller to parse with the values of a file (a capture's settings).
    """
    docs = field_docs(cls)
    hints = typing.get_type_hints(cls)
    group = parser.add_argument_group(title or f'{cls.__name__} options')
    for f in dataclasses.fields(cls):
        kind = _given(hints[f.name])
        path = prefix + f.name
        if dataclasses.is_dataclass(kind):
            add_arguments(parser, kind, default_note=default_note, prefix=path + '.', as_text=as_text)
            continue
        option = '--' + path.replace('.', '-').replace('_', '-')
        default = default_note or ('' if f.default is None else f.default)
        help_text = ' '.join(filter(None, (docs.get(f.name), default != '' and f'(default: {default})')))
        if as_text:
            group.add_argument(option, dest=path, default=None, metavar=f.name.upper(), help=help_text)
        elif kind is bool:
            group.add_argument(option, dest=path, action=argparse.BooleanOptionalAction, default=None,
                               help=help_text)
        elif typing.get_origin(kind) is tuple:
            items = typing.get_args(kind)
            group.add_argument(option, dest=path, type=_typed(items[0], path),
                               nargs='+' if Ellipsis in items else len(items), default=None,
                               metavar=items[0].__name__.upper(), help=help_text)
        else:
            group.add_argument(option, dest=path, type=_typed(kind, path), default=None,
                               metavar=kind.__name__.upper(), help=help_text)


def _given(kind):
    """The type of a value given for a field of type ``kind`` (``float | None``: float)."""
    args = [a for a in typing.get_args(kind) if a is not type(None)]
    return args[0] if type(None) in typing.get_args(kind) and len(args) == 1 else kind


def _typed(kind, path: str):
    """argparse's ``type``: the text typed as settings are, its error as argparse's."""
    def convert(text: str):
        try:
            return text_value(text, kind, path)
        except ReneusError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
    return convert


def given_arguments(cls, args: argparse.Namespace, prefix: str = '') -> dict:
    """The settings of ``cls`` that the user gave on the command line, by dotted path
    (``{'iterations': 10, 'refine.ior': True}``)."""
    hints = typing.get_type_hints(cls)
    given = {}
    for f in dataclasses.fields(cls):
        path = prefix + f.name
        if dataclasses.is_dataclass(hints[f.name]):
            given.update(given_arguments(hints[f.name], args, path + '.'))
        elif (value := getattr(args, path, None)) is not None:
            given[path] = tuple(value) if isinstance(value, list) else value
    return given
