"""Command-line options from a configuration dataclass.

Each field of the dataclass becomes ``--field-name``; the string literal that
follows the field in the class body (its docstring) becomes the help text, so
the documentation lives in one place.
"""
from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import textwrap
import typing


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


def add_arguments(parser: argparse.ArgumentParser, cls, *, skip=()) -> None:
    """Add one option per field of ``cls`` (defaults shown in the help)."""
    docs = field_docs(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        kind = hints[f.name]
        option = '--' + f.name.replace('_', '-')
        help_text = f'{docs.get(f.name, "")} (default: {f.default})'
        if kind is bool:
            parser.add_argument(option, action=argparse.BooleanOptionalAction, default=None, help=help_text)
        else:
            base = next((t for t in typing.get_args(kind) if t is not type(None)), kind)
            parser.add_argument(option, type=base, default=None, metavar=base.__name__.upper(), help=help_text)


def from_arguments(cls, args: argparse.Namespace, base=None):
    """Build ``cls`` from ``base`` (or the defaults) with the options the user gave."""
    given = {f.name: getattr(args, f.name) for f in dataclasses.fields(cls)
             if getattr(args, f.name, None) is not None}
    return dataclasses.replace(base or cls(), **given)
