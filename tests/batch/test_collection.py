"""A collection read from a folder or a manifest: names, kinds, settings, and one-line refusals."""
from __future__ import annotations

import json
import os

import pytest

from reneus_mi.batch.collection import read_collection
from reneus_mi.utils.errors import ReneusError


@pytest.fixture
def drawer(tmp_path):
    """A folder with two datasets and a capture (only the names of their metadata files are
    read here), and a stray folder."""
    for name in ('beetle', 'fly'):
        (tmp_path / 'drawer' / name).mkdir(parents=True)
        (tmp_path / 'drawer' / name / 'transforms.json').write_text('{}')
    photos = tmp_path / 'drawer' / 'moth'
    photos.mkdir()
    (photos / 'capture.json').write_text(json.dumps(
        {'squares': '12x9', 'square_mm': 20, 'marker_mm': 15, 'container': 'box', 'ior': 1.5}))
    (tmp_path / 'drawer' / 'notes').mkdir()
    return tmp_path / 'drawer'


def test_a_folder_of_datasets_and_captures(drawer):
    with pytest.warns(UserWarning, match='notes: left out: neither a dataset'):
        specimens = read_collection(str(drawer), preset='tiny', settings=['train.iterations=3'])
    assert [(s.name, s.kind, s.preset, s.settings) for s in specimens] == [
        ('beetle', 'dataset', 'tiny', ['train.iterations=3']), ('fly', 'dataset', 'tiny', ['train.iterations=3']),
        ('moth', 'capture', 'tiny', ['train.iterations=3'])]
    with pytest.raises(ReneusError, match='is one specimen'):
        read_collection(str(drawer / 'fly'))


def test_a_manifest(drawer, tmp_path):
    csv = tmp_path / 'm.csv'
    csv.write_text('name,data,preset,ior,train.iterations,model.render.max_depth,size_mm\n'
                   'b1,drawer/beetle,small,1.55,,3,\n'
                   ',drawer/fly,,,400,,\n'
                   'm,drawer/moth,,1.5,,,50x35x25\n')
    b1, fly, moth = read_collection(str(csv), preset='tiny', settings=['train.seed=2'])
    assert (b1.name, b1.preset, b1.ior, b1.settings) == ('b1', 'small', 1.55,
                                                         ['train.seed=2', 'model.render.max_depth=3'])
    assert (fly.name, fly.preset, fly.ior, fly.settings) == ('fly', 'tiny', None, ['train.seed=2', 'train.iterations=400'])
    assert fly.data == os.path.join(str(drawer), 'fly')
    assert (moth.kind, moth.capture, moth.ior) == ('capture', {'size_mm': '50x35x25'}, 1.5)
    js = tmp_path / 'm.json'
    js.write_text(json.dumps({'specimens': [{'data': 'drawer/beetle', 'train.iterations': 5,
                                             'train.refine.ior': True}]}))
    (beetle,) = read_collection(str(js))
    assert beetle.settings == ['train.iterations=5', 'train.refine.ior=true'] and beetle.preset == 'fast'


@pytest.mark.parametrize('text, expected', [
    ('name,data\nx,drawer/beetle\nX,drawer/fly\n', "name 'X' given twice"),
    ('name,data,colour\nx,drawer/beetle,red\n', "line 2: unknown column 'colour'"),
    ('name,data,train.iteration\nx,drawer/beetle,3\n', 'line 2: train.iteration: not a setting'),
    ('name,data,train.iterations\nx,drawer/beetle,many\n', "train.iterations='many': expected an integer"),
    ('name,data,ior\nx,drawer/beetle,0.9\n', r"ior='0.9'; expected a number in \(1, 3\]"),
    ('name,data,preset\nx,drawer/beetle,huge\n', "preset='huge'"),
    ('name,data\n_batch,drawer/beetle\n', "name '_batch'"),
    ('name,data\nsummary.csv,drawer/beetle\n', "name 'summary.csv'"),
    ('name,data\na/b,drawer/beetle\n', "name 'a/b'"),
    ('name\nx\n', "line 2: no 'data'"),
    ('name,data,size_mm\nx,drawer/beetle,50x35x25\n', 'capture settings .* not a capture folder'),
    ('name,data\n', 'names no specimen'),
])
def test_manifest_refusals(drawer, tmp_path, text, expected):
    path = tmp_path / 'm.csv'
    path.write_text(text)
    with pytest.raises(ReneusError, match=expected) as e:
        read_collection(str(path))
    assert '\n' not in str(e.value) and str(path) in str(e.value)


def test_json_manifest_refusals(drawer, tmp_path):
    path = tmp_path / 'm.json'
    for text, expected in (('{"data": 1}', 'expected a list of objects'), ('[1, 2]', 'expected a list of objects'),
                           ('[{"data": "x"', 'not a readable manifest')):
        path.write_text(text)
        with pytest.raises(ReneusError, match=expected):
            read_collection(str(path))
    with pytest.raises(ReneusError, match='no such collection'):
        read_collection(str(tmp_path / 'none.csv'))
    (tmp_path / 'm.txt').write_text('')
    with pytest.raises(ReneusError, match=r'a manifest is a \.csv or \.json file'):
        read_collection(str(tmp_path / 'm.txt'))


@pytest.mark.parametrize('encoding, separator', [('utf-8-sig', ','), ('utf-8-sig', ';'), ('utf-8', '\t')],
                         ids=['excel_csv_utf8', 'excel_semicolons', 'tabs'])
def test_a_manifest_as_spreadsheets_save_it(drawer, tmp_path, encoding, separator):
    """Excel's "CSV UTF-8" begins with a byte order mark, and where the decimal mark is a comma
    it separates with ';'. Harmful before: "unknown column '\\ufeffname'" and "line 2: no 'data'"."""
    path = tmp_path / 'm.csv'
    rows = [['name', 'data', 'ior'], ['b', 'drawer/beetle', '1.55'], ['f', 'drawer/fly', '']]
    path.write_bytes('\r\n'.join(separator.join(r) for r in rows).encode(encoding) + b'\r\n')
    b, f = read_collection(str(path))
    assert (b.name, b.ior, f.name, f.ior) == ('b', 1.55, 'f', None)
    assert b.data == os.path.join(str(drawer), 'beetle')


def test_a_manifest_not_in_utf8_named(drawer, tmp_path):
    path = tmp_path / 'm.csv'
    path.write_bytes('name,data\nkäfer,drawer/beetle\n'.encode('latin-1'))
    with pytest.raises(ReneusError, match=r'not UTF-8 text .*CSV UTF-8'):
        read_collection(str(path))


def test_a_manifest_carries_identifiers(drawer, tmp_path):
    """Darwin Core identifiers are columns: each specimen's exported package carries them."""
    path = tmp_path / 'm.csv'
    path.write_text('name,data,catalogNumber,occurrenceID,institutionCode\n'
                    'b,drawer/beetle,NHM 17,urn:x:17,NHM\nf,drawer/fly,NHM 18,,\n')
    b, f = read_collection(str(path))
    assert b.identifiers == {'catalogNumber': 'NHM 17', 'occurrenceID': 'urn:x:17', 'institutionCode': 'NHM'}
    assert f.identifiers == {'catalogNumber': 'NHM 18'}
