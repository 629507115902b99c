"""What a photographer states about a capture: the printed board, the container, the sizes.

The settings come from the command line (``--squares 12x9 --square-mm 20 ...``) or from a
small file beside the photographs, ``capture.json``, with the same names::

    {"board": "charuco", "squares": "12x9", "square_mm": 20, "marker_mm": 15,
     "dictionary": "DICT_4X4_100", "container": "box", "size_mm": "50x35x25", "ior": 1.5}

A setting given both ways must agree: a measured size is not something to override
silently. Every field's docstring is its command-line help
(:func:`reneus_mi.utils.cli.add_arguments`, as text: :func:`resolve` parses the options and
the file alike).
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import typing

from reneus_mi.data.checks import IOR_EXPECTED, valid_ior
from reneus_mi.geometry.shapes import CONTAINERS
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import load_json

#: The capture file looked for beside the photographs.
CAPTURE_FILE = 'capture.json'
#: ``size_mm`` of a container to measure from the photographs.
AUTO = 'auto'


@dataclasses.dataclass
class CaptureSettings:
    board: str = 'charuco'
    """Calibration target printed under the container (only 'charuco')."""
    squares: tuple[int, int] | None = None
    """Squares of the board along its columns and rows, e.g. 12x9 (not the inner corners)."""
    square_mm: float | None = None
    """Side of one printed square in millimetres, measured on the print."""
    marker_mm: float | None = None
    """Side of one printed ArUco marker in millimetres (smaller than a square)."""
    dictionary: str = 'DICT_4X4_100'
    """OpenCV ArUco dictionary of the markers, e.g. DICT_4X4_100, DICT_5X5_250."""
    container: str = 'box'
    """Container shape: box, rounded (a block with rounded edges) or cylinder (a jar)."""
    size_mm: tuple[float, float, float] | str | None = None
    """Outer size of the container in millimetres, WxDxH: its footprint on the board and its
    height (a cylinder: diameter x diameter x height); auto: measured from the photographs
    (report.json gives it with its uncertainty; calipers are better)."""
    edge_mm: float | None = None
    """Radius in millimetres of a rounded block's edges or of a jar's rims (0: sharp); not given:
    for a solid box, measured from the photographs (a polished block stated as a box becomes
    the rounded block they show, report.json's container.edge_mm); for the other shapes, 0.3 x
    the smallest half-size of the box the shape rounds (a moulded jar 40 mm across and 30
    high: 3.5 mm)."""
    ior: float | None = None
    """Index of refraction of the container (glass about 1.5, acrylic 1.49, epoxy resin 1.55)."""
    wall_mm: float | None = None
    """Thickness in millimetres of the walls of a hollow container (a display case: a box; a jar:
    a cylinder), lid and floor included; not given: a solid block."""
    liquid_ior: float | None = None
    """Index of refraction of the liquid that fills a hollow container (ethanol 1.36, water
    1.33); not given: air."""
    max_size: int | None = None
    """Largest side in pixels of the dataset's images (the photographs are scaled down to it)."""
    downscale: float | None = None
    """Divide the photographs' size by this factor for the dataset (instead of --max-size)."""
    container_pose: tuple[float, float, float] | None = None
    """The container's place on the board, x,y,yaw (mm, mm, degrees), when it is not found
    automatically: the centre of its footprint and the angle of its W side from the board's x."""

    def check(self, where: str | dict[str, str]) -> 'CaptureSettings':
        """Raise one line naming every setting that is missing, out of range or contradicts
        another, each with where it was given: ``where`` is one place for all settings, or the
        place of each by name (``--max-size``, the capture file; ``''``: where none was given)."""
        def place(name: str) -> str:
            return where if isinstance(where, str) else where.get(name, where.get('', 'capture settings'))
        problems = []

        def problem(name: str, text: str) -> None:
            problems.append(f'{place(name)}: {text}')
        for name in ('squares', 'square_mm', 'marker_mm', 'size_mm', 'ior'):
            if getattr(self, name) is None:
                problem('', f"{name} is not given; expected --{_flag(name)} or '{name}' in {CAPTURE_FILE}")
        if problems:
            _raise(problems)
        if self.board != 'charuco':
            problem('board', f"board={self.board!r}; expected 'charuco'")
        if self.container not in CONTAINERS:
            problem('container', f"container={self.container!r}; expected one of {', '.join(CONTAINERS)}")
        columns, rows = self.squares
        if min(columns, rows) < 3:
            problem('squares', f"squares={columns}x{rows}; expected at least 3x3 squares")
        if self.edge_mm is not None:
            if not self.edge_mm >= 0:
                problem('edge_mm', f"edge_mm={self.edge_mm:g}; expected a radius >= 0 in millimetres")
            elif self.container == 'box' and self.edge_mm > 0:
                problem('edge_mm', f"edge_mm={self.edge_mm:g} for a box; expected --container rounded for "
                                   "a block with rounded edges")
            elif self.size_mm not in (None, AUTO) and not self.edge_mm < 0.5 * min(self.size_mm):
                problem('edge_mm', f"edge_mm={self.edge_mm:g} and size_mm={_x(self.size_mm)} contradict each "
                                   "other; expected a radius below half the smallest side")
        for name in ('square_mm', 'marker_mm', 'wall_mm'):
            value = getattr(self, name)
            if value is not None and not value > 0:
                problem(name, f"{name}={value:g}; expected a positive size in millimetres")
        if self.size_mm != AUTO and min(self.size_mm) <= 0:
            problem('size_mm', f"size_mm={_x(self.size_mm)}; expected positive sizes")
        sizes_make_sense = not problems     # the comparisons below need every size positive
        for name in ('ior', 'liquid_ior'):
            value = getattr(self, name)
            if value is not None and not valid_ior(value):
                problem(name, f"{name}={value:g}; expected {IOR_EXPECTED} "
                              f"({'glass: about 1.5' if name == 'ior' else 'ethanol: 1.36'})")
        if sizes_make_sense:
            self._compare_sizes(problem)
        if self.liquid_ior is not None and self.wall_mm is None:
            problem('liquid_ior', f"liquid_ior={self.liquid_ior:g} without wall_mm; expected the thickness "
                                  "of the walls that hold the liquid (--wall-mm)")
        if self.max_size is not None and self.downscale is not None:
            problem('max_size', f"max_size={self.max_size} and downscale={self.downscale:g} both given; "
                                "expected one of them")
        if self.max_size is not None and self.max_size < 64:
            problem('max_size', f"max_size={self.max_size}; expected at least 64 pixels")
        if self.downscale is not None and not self.downscale >= 1.0:
            problem('downscale', f"downscale={self.downscale:g}; expected a factor >= 1")
        if problems:
            _raise(problems)
        return self

    def _compare_sizes(self, problem) -> None:
        """The checks between sizes, each positive: marker and square, container and board, a
        cylinder's diameters, the walls (of a size stated, not measured)."""
        columns, rows = self.squares
        if not self.marker_mm < self.square_mm:
            problem('marker_mm', f"marker_mm={self.marker_mm:g} and square_mm={self.square_mm:g} contradict "
                                 "each other; expected a marker smaller than its square")
        if self.size_mm == AUTO:    # measured from the photographs, checked there
            return
        width, depth, _ = self.size_mm
        board = (columns * self.square_mm, rows * self.square_mm)
        if max(width, depth) > max(board) or width * depth > board[0] * board[1]:
            problem('size_mm', f"size_mm={_x(self.size_mm)} and the board ({_x(board)} mm: squares "
                               f"{columns}x{rows} of {self.square_mm:g} mm) contradict each other; expected a "
                               "container that stands on the board")
        if self.container == 'cylinder' and width != depth:
            problem('size_mm', f"size_mm={_x(self.size_mm)} for a cylinder; expected diameter x diameter x "
                               "height (equal first two)")
        if self.wall_mm is not None and not 2 * self.wall_mm < min(self.size_mm):
            problem('wall_mm', f"wall_mm={self.wall_mm:g} and size_mm={_x(self.size_mm)} contradict each "
                               "other; expected a positive wall thinner than half the smallest size")


def _raise(problems: list[str]) -> None:
    """All the settings' problems in one line."""
    if len(problems) == 1:
        raise ReneusError(problems[0])
    raise ReneusError(f'{len(problems)} problems with the capture settings: ' + '; '.join(problems))


def _flag(name: str) -> str:
    return name.replace('_', '-')


def _x(values) -> str:
    return 'x'.join(f'{v:g}' for v in values)


def numbers(text, count: int, kind, sep: str, name: str, where: str) -> tuple:
    """``'12x9'``, ``[12, 9]`` or ``'1,2,3'`` as a tuple of ``count`` numbers of ``kind``."""
    parts = text.split(sep) if isinstance(text, str) else text
    try:
        if not isinstance(parts, (list, tuple)) or len(parts) != count:
            raise ValueError
        values = tuple(kind(float(p)) if kind is int and float(p) == int(float(p)) else kind(p)
                       for p in parts)
        if not all(math.isfinite(v) for v in values):
            raise ValueError
    except (TypeError, ValueError):
        example = sep.join(['12', '9'] if count == 2 else ['50', '35', '25'])
        raise ReneusError(f"{where}: {name}={text!r}; expected {count} numbers like {example}") from None
    return values


#: How each field is written: (count, type, separator) for the tuples, the type otherwise.
_FORMATS = {'squares': (2, int, 'x'), 'size_mm': (3, float, 'x'), 'container_pose': (3, float, ',')}


def _parse(name: str, value, where: str):
    if value is None:
        return None
    if name == 'size_mm' and value == AUTO:
        return AUTO
    if name in _FORMATS:
        return numbers(value, *_FORMATS[name], name, where)
    kind = typing.get_type_hints(CaptureSettings)[name]
    base = next((k for k in typing.get_args(kind) if k is not type(None)), kind)
    try:
        if base is str:
            if not isinstance(value, str):
                raise ValueError
            return value
        if isinstance(value, bool) or (base is int and float(value) != int(float(value))):
            raise ValueError
        number = base(float(value)) if base is int else base(value)
        if not math.isfinite(number):
            raise ValueError
        return number
    except (TypeError, ValueError):
        raise ReneusError(f"{where}: {name}={value!r}; expected {'a text' if base is str else 'a number'}") from None


def resolve(args: argparse.Namespace | dict, photos: str, settings_file: str | None = None) -> CaptureSettings:
    """The settings from the command line and the capture file (``photos/capture.json`` unless
    ``settings_file`` names one), checked. A setting given both ways must agree."""
    given = vars(args) if isinstance(args, argparse.Namespace) else dict(args)
    path = settings_file or os.path.join(photos, CAPTURE_FILE)
    stored = {}
    if settings_file is not None or os.path.isfile(path):
        stored = load_json(path, 'capture settings')
    names = [f.name for f in dataclasses.fields(CaptureSettings)]
    unknown = sorted(set(stored) - set(names))
    if unknown:
        raise ReneusError(f"{path}: unknown setting(s) {', '.join(unknown)}; expected some of {', '.join(names)}")
    values, where, problems = {}, {'': path if stored else 'capture settings'}, []
    for name in names:
        try:
            flag = _parse(name, given.get(name), f'--{_flag(name)}')
            kept = _parse(name, stored.get(name), path)
        except ReneusError as e:
            problems.append(str(e))
            continue
        if flag is not None and kept is not None and flag != kept:
            problems.append(f"--{_flag(name)} {given[name]} contradicts {name}={stored[name]!r} in {path}; "
                            "expected one value (give it once)")
            continue
        if flag is not None or kept is not None:
            values[name] = flag if flag is not None else kept
            where[name] = f'--{_flag(name)}' if flag is not None else path
    if problems:
        _raise(problems)
    return CaptureSettings(**values).check(where)


def to_json(settings: CaptureSettings) -> dict:
    """The settings as a capture file holds them (what :func:`resolve` reads back)."""
    out = {}
    for f in dataclasses.fields(CaptureSettings):
        value = getattr(settings, f.name)
        if value is None:
            continue
        if f.name in _FORMATS and value != AUTO:
            _, kind, sep = _FORMATS[f.name]
            value = sep.join(f'{v:g}' for v in value)
        out[f.name] = value
    return out
