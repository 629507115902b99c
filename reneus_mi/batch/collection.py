"""A collection of specimens: a folder of dataset (or capture) folders, or a manifest.

A folder: every subfolder that holds a dataset (``transforms.json``,
``cameras_sphere.npz``) or a capture (photographs and ``capture.json``,
:mod:`reneus_mi.capture`) is a specimen named after it. A manifest, CSV or
JSON (a list of objects, or ``{"specimens": [...]}``), names them one a row::

    name,data,preset,ior,train.iterations
    beetle_07,drawer3/beetle_07,fast,1.55,
    fly_12,drawer3/fly_12_photos,,,4000

=================== ==========================================================
column              what
=================== ==========================================================
``data``            the dataset or capture folder (relative to the manifest)
``name``            the run folder's name (default: the data folder's name)
``preset``          the preset the run starts from (default: ``--preset``)
``ior``             the container's IOR, over the dataset's (a capture's setting)
``catalogNumber``   Darwin Core identifiers (also ``occurrenceID``, ``institutionCode``)
                    that the specimen's exported package carries (:mod:`reneus_mi.export.package`)
``size_mm`` ...     a capture setting (:class:`~reneus_mi.capture.settings.CaptureSettings`:
                    the container's size, the board), over ``capture.json``
``train.iterations`` any setting by its dotted path, as ``--set`` takes it
=================== ==========================================================

An empty cell gives nothing. The names, presets and settings are checked when
the manifest is read (a typo stops the batch before any run); a specimen's
data, its capture settings included, is checked by its own run, which fails
alone.
"""
from __future__ import annotations

import csv
import dataclasses
import io
import json
import os
import re
import warnings
from dataclasses import dataclass, field

from reneus_mi.batch.batch_folder import RESERVED
from reneus_mi.capture.settings import CAPTURE_FILE, CaptureSettings
from reneus_mi.config import with_settings
from reneus_mi.data.checks import IOR_EXPECTED, valid_ior
from reneus_mi.export.package import IDENTIFIERS
from reneus_mi.presets import preset
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError

#: What a specimen's data folder is: a dataset, or photographs to capture a dataset from.
KINDS = ('dataset', 'capture')
#: The separators a CSV manifest may use, the most frequent in its header line taken.
CSV_SEPARATORS = (',', ';', '\t')
#: A name is a run folder's name: no separators, nothing hidden, nothing of the batch's own.
NAME = re.compile(r'[A-Za-z0-9][A-Za-z0-9._+-]*')


@dataclass
class Specimen:
    """One specimen of a collection: its data, and how its run differs from the others'."""
    name: str
    """The run folder's name under the batch folder."""
    data: str
    """The dataset folder, or the capture folder (photographs and capture.json)."""
    kind: str = 'dataset'
    """dataset or capture."""
    preset: str = 'fast'
    """The preset the run starts from."""
    settings: list[str] = field(default_factory=list)
    """Settings over the preset, PATH=VALUE (model.* and train.*), in order."""
    ior: float | None = None
    """The container's IOR, over the dataset's."""
    capture: dict = field(default_factory=dict)
    """Capture settings over the capture folder's capture.json (a capture's only)."""
    identifiers: dict = field(default_factory=dict)
    """Darwin Core identifiers (catalogNumber, ...) that its exported package carries."""

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict) -> 'Specimen':
        return Specimen(**d)


def kind_of(folder: str) -> str | None:
    """``dataset`` or ``capture`` for a specimen's folder, None for anything else."""
    if guards.is_dataset_dir(folder):
        return 'dataset'
    if os.path.isfile(os.path.join(folder, CAPTURE_FILE)):
        return 'capture'
    return None


def read_collection(path: str, *, preset: str = 'fast', settings=()) -> list[Specimen]:
    """The specimens of a collection folder or manifest; ``preset`` and ``settings``
    (PATH=VALUE) apply to each, under what a manifest's row says."""
    if os.path.isdir(path):
        if kind_of(path):
            raise ReneusError(f'{path}: is one specimen ({kind_of(path)} folder); expected a folder of '
                              'them or a manifest (python -m reneus_mi.optimize runs one)')
        specimens = _from_folder(path, preset, list(settings))
    elif os.path.isfile(path):
        rows = _manifest_rows(path)
        specimens = [_from_row(row, f'{path}: {where}', os.path.dirname(os.path.abspath(path)),
                               preset, list(settings)) for where, row in rows]
        if not specimens:
            raise ReneusError(f'{path}: the manifest names no specimen; expected a row per specimen')
    else:
        raise ReneusError(f'{path}: no such collection; expected a folder of datasets or a manifest '
                          '(.csv, .json)')
    seen = {}
    for s in specimens:
        if s.name.lower() in seen:
            raise ReneusError(f'{path}: name {s.name!r} given twice ({seen[s.name.lower()]} and {s.data}); '
                              'expected one run folder per specimen')
        seen[s.name.lower()] = s.data
    return specimens


def _from_folder(folder: str, preset: str, settings: list[str]) -> list[Specimen]:
    specimens = []
    for name in sorted(os.listdir(folder)):
        sub = os.path.join(folder, name)
        if name.startswith('.') or not os.path.isdir(sub):
            continue
        kind = kind_of(sub)
        if kind is None:
            warnings.warn(f'{sub}: left out: neither a dataset (transforms.json, cameras_sphere.npz) '
                          'nor a capture folder (capture.json)')
            continue
        specimens.append(_checked(Specimen(name, os.path.abspath(sub), kind, preset, list(settings)), sub))
    if not specimens:
        raise ReneusError(f'{folder}: holds no dataset or capture folder; expected a folder of them')
    return specimens


def _manifest_rows(path: str) -> list[tuple[str, dict]]:
    """(where, row) of each specimen of a CSV or JSON manifest, empty cells left out."""
    ext = os.path.splitext(path)[1].lower()
    try:
        # utf-8-sig: Excel's "CSV UTF-8" begins with a byte order mark.
        with open(path, newline='', encoding='utf-8-sig') as f:
            if ext == '.csv':
                text = f.read()
                header = text.splitlines()[0] if text.strip() else ''
                # Excel writes ';' where the decimal mark is a comma, some tools a tab.
                separator = max(CSV_SEPARATORS, key=header.count)
                reader = csv.DictReader(io.StringIO(text), delimiter=separator)
                rows = [(f'line {reader.line_num}', {k.strip(): v.strip() for k, v in row.items()
                                                     if k is not None and v is not None and v.strip()})
                        for row in reader]
                if None in (reader.fieldnames or [None]):
                    raise ReneusError(f'{path}: no header line; expected one like name,data,preset')
                return rows
            if ext == '.json':
                data = json.load(f)
            else:
                raise ReneusError(f'{path}: a manifest is a .csv or .json file')
    except OSError as e:
        raise ReneusError(f'{path}: cannot read the manifest ({e.strerror})') from None
    except UnicodeDecodeError as e:
        raise ReneusError(f'{path}: not UTF-8 text (byte {e.start}); expected a manifest saved as UTF-8 '
                          '(Excel: "CSV UTF-8")') from None
    except (ValueError, csv.Error) as e:
        if isinstance(e, ReneusError):
            raise
        raise ReneusError(f'{path}: not a readable manifest ({e})') from None
    if isinstance(data, dict) and isinstance(data.get('specimens'), list):
        data = data['specimens']
    if not isinstance(data, list) or not all(isinstance(r, dict) for r in data):
        raise ReneusError(f'{path}: expected a list of objects (or {{"specimens": [...]}}), one per specimen')
    return [(f'specimen {i + 1}', {k: v for k, v in r.items() if v is not None and v != ''})
            for i, r in enumerate(data)]


def _from_row(row: dict, where: str, base: str, preset: str, settings: list[str]) -> Specimen:
    capture_names = {f.name for f in dataclasses.fields(CaptureSettings)} - {'ior'}
    row = dict(row)
    if 'data' not in row:
        raise ReneusError(f"{where}: no 'data'; expected the specimen's dataset or capture folder")
    data = os.path.normpath(os.path.join(base, str(row.pop('data'))))
    name = str(row.pop('name', os.path.basename(data)))
    specimen = Specimen(name, data, kind_of(data) or 'dataset', str(row.pop('preset', preset)), list(settings))
    if 'ior' in row:
        value = row.pop('ior')
        try:
            specimen.ior = float(value)
        except (TypeError, ValueError):
            specimen.ior = float('nan')
        if not valid_ior(specimen.ior):
            raise ReneusError(f'{where}: ior={value!r}; expected {IOR_EXPECTED}')
    for key, value in row.items():
        if key in IDENTIFIERS:
            specimen.identifiers[key] = str(value)
        elif '.' in key:
            specimen.settings.append(f'{key}={_text(value)}')
        elif key in capture_names:
            specimen.capture[key] = value
        else:
            raise ReneusError(f"{where}: unknown column {key!r}; expected name, data, preset, ior, "
                              f"{', '.join(IDENTIFIERS)}, a capture setting (size_mm, squares, ...) or a "
                              "setting's dotted path (train.iterations)")
    return _checked(specimen, where)


def _text(value) -> str:
    """A JSON value as --set writes it."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return ','.join(map(str, value))
    return str(value)


def _checked(s: Specimen, where: str) -> Specimen:
    """``s`` once its name, preset and settings are known good (its data is its run's to check)."""
    if not NAME.fullmatch(s.name) or s.name in RESERVED:
        raise ReneusError(f'{where}: name {s.name!r}; expected letters, digits and . _ + - (a folder name, '
                          'not starting with a dot or _, not a summary file)')
    try:
        with_settings(preset(s.preset), s.settings)
    except ReneusError as e:
        raise ReneusError(f'{where}: {e}') from None
    if s.capture and s.kind != 'capture':
        raise ReneusError(f"{where}: capture settings ({', '.join(s.capture)}) for {s.data}, which is not a "
                          'capture folder (photographs and capture.json)')
    return s
