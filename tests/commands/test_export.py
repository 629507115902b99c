"""A specimen's package (``python -m reneus_mi.export``): the mesh as the run wrote it, the
identifiers and paradata a collection imports, and refusals."""
from __future__ import annotations

import csv
import json
import os
import re
import shutil
import subprocess
import zipfile

import numpy as np
import pytest
import trimesh
from PIL import Image

from reneus_mi import optimize
from reneus_mi.data import load_dataset
from reneus_mi.export import __main__ as export_command, package as export
from reneus_mi.utils.errors import ReneusError

IDS = {'catalogNumber': 'NHM 2026/17', 'occurrenceID': 'urn:catalog:NHM:ENT:2026-17', 'institutionCode': 'NHM'}


@pytest.fixture(scope='module')
def finished(scene_xml, tmp_path_factory):
    """A short run of the tiny statuette that ends with its mesh."""
    run = tmp_path_factory.mktemp('export') / 'run'
    assert optimize.main([scene_xml, '-o', str(run), '--iterations', '30', '--batch-rays', '256',
                          '--validate-every', '0', '--mesh-resolution', '32', '--quiet']) == 0
    with open(run / 'result.json') as f:
        assert 'failure' not in json.load(f)
    return run


def test_package_of_a_run(finished, tmp_path):
    out = tmp_path / 'package'
    metadata = export.export_run(str(finished), str(out), identifiers=IDS, creator='A. Curator')
    name = 'NHM_2026_17'
    assert sorted(os.listdir(out)) == sorted([f'{name}.ply', f'{name}.glb', f'{name}.html', 'metadata.json',
                                              'record.csv', 'manifest-sha256.txt'])
    # Fixity: every other file with its SHA-256, as `sha256sum -c` reads it.
    fixity = dict(line.split('  ')[::-1] for line in (out / 'manifest-sha256.txt').read_text().splitlines())
    assert sorted(fixity) == sorted(set(os.listdir(out)) - {'manifest-sha256.txt'})
    assert subprocess.run(['sha256sum', '-c', '--quiet', 'manifest-sha256.txt'], cwd=out).returncode == 0
    # The mesh as the run wrote it, vertex for vertex, with its colours.
    mine, theirs = trimesh.load(out / f'{name}.ply', process=False), trimesh.load(finished / 'mesh.ply', process=False)
    np.testing.assert_allclose(mine.vertices, theirs.vertices)
    assert np.array_equal(mine.visual.vertex_colors, theirs.visual.vertex_colors)
    web = trimesh.load(out / f'{name}.glb', force='mesh', process=False)
    assert len(web.vertices) == len(theirs.vertices)
    assert _gltf_problems(out / f'{name}.glb') == []
    with open(out / 'metadata.json') as f:
        assert json.load(f) == json.loads(json.dumps(metadata, default=float))
    assert metadata['dwc'] == IDS and metadata['ac']['dc:creator'] == 'A. Curator'
    assert metadata['ac']['dcterms:format'] == 'model/gltf-binary'
    # Audiovisual Core's proposed 3D terms (tdwg/ac#243) beside the keys above.
    # They describe the master mesh (NAME.ply: no colours; the GLB carries the field's).
    with open(finished / 'config.json') as f:
        views = len(load_dataset(json.load(f)['data']).names)
    with open(finished / 'result.json') as f:
        units = json.load(f).get('units')
    terms = ('ac:3DResourceType', 'ac:pointCount', 'ac:faceCount', 'ac:colorBoolean', 'ac:numberOfImages',
             'bf:Unit')
    assert {k: metadata['ac'][k] for k in terms} == {
        'ac:3DResourceType': 'polygonal mesh', 'ac:pointCount': len(theirs.vertices),
        'ac:faceCount': len(theirs.faces), 'ac:colorBoolean': 'False', 'ac:numberOfImages': views,
        'bf:Unit': units}
    np.testing.assert_allclose(metadata['mesh']['extent'], theirs.extents, atol=1e-4)
    # Length, width, height: at least the extent along the longest axis, sorted.
    size = metadata['mesh']['size']
    assert size == sorted(size, reverse=True) and size[0] >= max(theirs.extents) - 1e-4
    with open(finished / 'config.json') as f:
        assert metadata['paradata']['configuration'] == json.load(f)
    training = metadata['paradata']['training']
    assert training['iterations'] == 30 and training['psnr'] > 0
    assert metadata['paradata']['container']['ior_given'] == pytest.approx(1.45)
    assert metadata['paradata']['software']['version']
    with open(out / 'record.csv', newline='') as f:
        (row,) = list(csv.DictReader(f))
    assert {k: row[k] for k in IDS} == IDS and row['file'] == f'{name}.glb' and row['steps'] == '30'
    assert float(row['extent_x']) == pytest.approx(theirs.extents[0], abs=1e-3)


#: Khronos' glTF Validator, as ``bash setup.sh test`` installs it (npm's build of it).
GLTF_VALIDATOR = os.path.join(os.path.dirname(__file__), '..', '..', '.cache', 'gltf-validator', 'node_modules',
                              'gltf-validator')


def _gltf_problems(path) -> list[str]:
    """The errors and warnings the glTF Validator finds in a GLB (its hints and notes aside)."""
    assert os.path.isdir(GLTF_VALIDATOR), 'no glTF Validator: bash setup.sh test installs it (npm)'
    script = ("const v = require(process.argv[1]);"
              "v.validateBytes(new Uint8Array(require('fs').readFileSync(process.argv[2])))"
              ".then(r => console.log(JSON.stringify(r.issues.messages)))")
    done = subprocess.run(['node', '-e', script, os.path.abspath(GLTF_VALIDATOR), str(path)], capture_output=True,
                          text=True, timeout=120, check=True)
    return [f"{m['code']} at {m.get('pointer')}" for m in json.loads(done.stdout) if m['severity'] <= 1]


def test_large_model_gets_an_access_copy_under_the_limit(finished, tmp_path, monkeypatch):
    """A GLB over the limit (here a fifth of this one's size) gets a simplified copy under it:
    the same shape (its box to a percent), coloured, named in the metadata and the fixity."""
    limit = os.path.getsize(finished / 'mesh.glb') // 5
    monkeypatch.setattr(export, 'ACCESS_MAX_BYTES', limit)
    out = tmp_path / 'package'
    metadata = export.export_run(str(finished), str(out))
    name = metadata['files']['access_mesh']
    assert os.path.getsize(out / name) <= limit
    full = trimesh.load(out / metadata['files']['web_mesh'], force='mesh', process=False)
    small = trimesh.load(out / name, force='mesh', process=False)
    assert metadata['mesh']['access_faces'] == len(small.faces) < len(full.faces) / 3
    np.testing.assert_allclose(small.bounds, full.bounds, atol=0.02 * full.extents.max())
    _, near = trimesh.proximity.ProximityQuery(full).vertex(small.vertices)
    colours = np.asarray(small.visual.vertex_colors)[:, :3].astype(float)
    assert np.abs(colours - np.asarray(full.visual.vertex_colors)[near, :3]).mean() < 8
    assert name in (out / 'manifest-sha256.txt').read_text()
    assert _gltf_problems(out / name) == []


def test_watertight_variant_says_what_it_closed(tmp_path):
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    box.update_faces(np.arange(len(box.faces)) != 0)     # one triangle missing: one hole
    box.remove_unreferenced_vertices()
    assert export._boundary_loops(box) == 1 and not box.is_watertight
    closed = export._watertight(box)
    assert closed['holes_closed'] == 1 and closed['holes_left'] == 0 and closed['watertight']
    assert closed['mesh'].is_watertight


def test_command_line_zip_and_batch_identifiers(finished, tmp_path):
    """A batch folder: each finished specimen's package carries its manifest row's identifiers
    (the command line's win)."""
    runs = tmp_path / 'runs'
    shutil.copytree(finished, runs / 'beetle')
    (runs / '_batch').mkdir()
    (runs / '_batch' / 'collection.json').write_text(json.dumps([
        {'name': 'beetle', 'data': str(finished), 'identifiers': dict(IDS, catalogNumber='B-1')},
        {'name': 'fly', 'data': str(finished), 'identifiers': {'catalogNumber': 'F-2'}}]))
    out = tmp_path / 'packages'
    assert export_command.main([str(runs), '-o', str(out), '--institutionCode', 'OUM', '--zip']) == 0
    assert os.listdir(out) == ['B-1']      # the fly never ran
    with open(out / 'B-1' / 'metadata.json') as f:
        assert json.load(f)['dwc'] == dict(IDS, catalogNumber='B-1', institutionCode='OUM')
    with zipfile.ZipFile(str(out) + '.zip') as z:
        assert 'B-1/B-1.ply' in z.namelist()


def test_zip_never_replaces_a_file(finished, tmp_path):
    """PACKAGE.zip that the command did not make is refused before anything is written."""
    (tmp_path / 'package.zip').write_text('mine')
    with pytest.raises(SystemExit, match='package archive .*package.zip: exists') as refusal:
        export_command.main([str(finished), '-o', str(tmp_path / 'package'), '--zip'])
    # export has no --overwrite: the message does not send anyone to it.
    assert '--overwrite' not in str(refusal.value) and 'move that file away' in str(refusal.value)
    assert (tmp_path / 'package.zip').read_text() == 'mine' and not (tmp_path / 'package').exists()


@pytest.mark.parametrize('value, parts', [
    ('NHM\n2026/17', ['catalogNumber=', "control character '\\n'", 'one line']),
    ('N' * 300, ['catalogNumber: 300 characters', f'at most {export.MAX_IDENTIFIER}']),
], ids=['newline', 'too_long'])
def test_identifiers_refused_before_anything_is_written(finished, tmp_path, value, parts):
    with pytest.raises(SystemExit) as refusal:
        export_command.main([str(finished), '-o', str(tmp_path / 'package'), '--catalogNumber', value])
    for part in parts:
        assert part in str(refusal.value), str(refusal.value)
    assert not (tmp_path / 'package').exists()


def test_record_cell_that_a_spreadsheet_would_run_is_quoted(finished, tmp_path):
    """A catalogue number starting with '=' (or +, -, @) reaches a spreadsheet as text."""
    export.export_run(str(finished), str(tmp_path / 'package'), identifiers={'catalogNumber': '=HYPERLINK("x")',
                                                                            'institutionCode': 'NHM'})
    with open(tmp_path / 'package' / 'record.csv', newline='') as f:
        (row,) = list(csv.DictReader(f))
    assert row['catalogNumber'] == "'=HYPERLINK(\"x\")" and row['institutionCode'] == 'NHM'
    assert float(row['extent_x']) > 0       # numbers stay numbers


def test_batch_refuses_one_catalogue_number_for_several_and_names_what_it_leaves_out(finished, tmp_path,
                                                                                       capsys):
    runs = tmp_path / 'runs'
    shutil.copytree(finished, runs / 'beetle')
    shutil.copytree(finished, runs / 'wasp')
    (runs / '_batch').mkdir()
    (runs / '_batch' / 'collection.json').write_text(json.dumps([
        {'name': n, 'data': str(finished), 'identifiers': {}} for n in ('beetle', 'wasp', 'fly')]))
    with pytest.raises(SystemExit, match=r"--catalogNumber 'B-1' for 2 specimens \(beetle, wasp\)"):
        export_command.main([str(runs), '-o', str(tmp_path / 'packages'), '--catalogNumber', 'B-1'])
    assert not (tmp_path / 'packages').exists()
    assert export_command.main([str(runs), '-o', str(tmp_path / 'packages')]) == 0
    assert sorted(os.listdir(tmp_path / 'packages')) == ['beetle', 'wasp']
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith('warning: ')]
    assert warnings == ['warning: fly: left out: its run is new'], warnings


def test_liquid_ior_from_the_datasets_interfaces(tmp_path):
    """A jar stated as interfaces (no capture report): the liquid's IOR is the innermost one's."""
    (tmp_path / 'transforms.json').write_text(json.dumps({'IOR': 1.5, 'containers': [
        {'mesh': 'glass.ply', 'int_ior': 1.5, 'ext_ior': 1.0},
        {'mesh': 'liquid.ply', 'int_ior': 1.36, 'ext_ior': 1.5}]}))
    container = export._container(str(tmp_path), {'refined': {'container.inner_ior': 1.355}})
    assert container['liquid_ior_given'] == 1.36 and container['liquid_ior_refined'] == 1.355


def test_unfinished_run_refused(finished, tmp_path):
    run = tmp_path / 'run'
    shutil.copytree(finished, run)
    (run / 'result.json').unlink()
    with pytest.raises(ReneusError, match='not a finished run'):
        export.export_run(str(run), str(tmp_path / 'package'))
    with pytest.raises(ReneusError, match='package folder .* lies inside the input'):
        export.export_run(str(finished), str(finished / 'package'))


def _chromium(*args) -> subprocess.CompletedProcess:
    """Headless Chromium (Debian's package; ``bash setup.sh test`` installs it), WebGL in software."""
    browser = shutil.which('chromium') or shutil.which('chromium-browser')
    assert browser, 'no chromium: bash setup.sh test installs it (apt-get install -y chromium)'
    return subprocess.run([browser, '--headless', '--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
                           '--virtual-time-budget=20000', *args], capture_output=True, text=True, timeout=180)


def test_report_page_in_a_real_browser(finished, tmp_path):
    """The page opens from disk with no network: the viewer shows the model (the middle of the
    viewer is not its background) and no error reached the console."""
    out = tmp_path / 'package'
    export.export_run(str(finished), str(out), identifiers={'catalogNumber': 'B-1'})
    page = out / 'B-1.html'
    text = page.read_text()
    # Nothing the page loads lies elsewhere: the component and the model are in it.
    assert not re.search(r'(src|href)="(https?:)?//', text) and '<model-viewer id="model"' in text
    dom = _chromium('--dump-dom', page.as_uri()).stdout
    body = re.search(r'<body[^>]*>', dom).group(0)
    assert 'data-state="loaded"' in body and 'data-errors=""' in body, body
    shot = tmp_path / 'shot.png'
    _chromium('--window-size=1000,700', f'--screenshot={shot}', page.as_uri())
    image = np.asarray(Image.open(shot).convert('RGB'), float)
    viewer = np.array([0x2b, 0x2f, 0x36], float)
    # The viewer spans the page's width below the title; its middle shows the model.
    middle = image[330:370, 480:520].reshape(-1, 3)
    assert np.abs(middle - viewer).max(axis=1).mean() > 40, middle.mean(axis=0)
    corner = image[560:570, 60:70].reshape(-1, 3)        # the viewer's own background beside it
    assert np.abs(corner - viewer).max() < 12, corner.mean(axis=0)
