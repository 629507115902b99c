"""A finished run as a specimen's package for a collection's systems (MorphoSource, a
museum's collection database, a web viewer): what ``python -m reneus_mi.export RUN -o
PACKAGE`` writes (:mod:`reneus_mi.export.__main__`).

Layout of ``PACKAGE`` (``--zip``: also ``PACKAGE.zip``)::

    NAME.ply              the mesh with vertex colours, in the run's units (a capture's:
                          millimetres in the board's frame)
    NAME.glb              the same for web viewers (glTF: metres, y up)
    NAME_access.glb       where NAME.glb exceeds ACCESS_MAX_BYTES (20 MB): a simplified copy
                          under it, for viewers and portals that limit uploads (and the page)
    NAME.html             the report page: the model to turn, with a scale bar, renders,
                          photographs, overlays, figures; self-contained (:mod:`reneus_mi.page`)
    NAME_watertight.ply   (--watertight) the mesh with its holes closed; metadata.json says
                          how many were closed and whether it is watertight
    metadata.json         the identifiers (Darwin Core), the media terms (Audubon Core) and the
                          paradata: camera, board, container as given and as refined, the
                          calibration's figures, the training's, the software and the whole
                          configuration (docs/export.md)
    record.csv            one header and one row: what a collection database imports
    manifest-sha256.txt   every other file's SHA-256 (BagIt's manifest): fixity

NAME is the catalogue number when there is one, else the run folder's name. The
identifiers come from the command line or, for a batch folder (every finished specimen
exported into ``PACKAGE/NAME``), from the manifest's columns of the same names.
"""
from __future__ import annotations

import csv
import datetime
import hashlib
import io
import json
import os
import shutil
import subprocess
from importlib.metadata import version

import numpy as np
import trimesh

from reneus_mi.data import load_dataset
from reneus_mi.geometry.mesh import decimated_glb, load_mesh
from reneus_mi.geometry.surface import components
from reneus_mi.train.run_folder import RunFolder
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError
from reneus_mi.export.page import write_page
from reneus_mi.utils.io import atomic_export, atomic_write_text, read_json

#: Darwin Core identifiers a package carries (command-line options and manifest columns).
IDENTIFIERS = ('catalogNumber', 'occurrenceID', 'institutionCode')
#: Longest identifier taken: a catalogue number names the package's files, and file systems
#: take 255 bytes a name (a URI occurrenceID runs to a few dozen characters).
MAX_IDENTIFIER = 200
#: The package's fixity: each file's SHA-256 (BagIt's manifest format).
FIXITY = 'manifest-sha256.txt'
#: What a spreadsheet reads as the start of a formula in a cell of record.csv.
FORMULA_START = ('=', '+', '-', '@', '\t', '\r')
#: Audubon Core's description of how the model was made.
CREATION_TECHNIQUE = ('3D surface reconstructed from photographs taken through the transparent container '
                      'that holds the specimen (ReNeuS, CVPR 2023: refraction and reflection at the '
                      "container's surfaces traced, a neural signed distance field fitted inside), with reneus-mi")
#: Largest GLB a web viewer or portal is given (MorphoSource's 3D viewer and Sketchfab's free
#: uploads work best below a few tens of MB): a larger master gets a simplified access copy.
ACCESS_MAX_BYTES = 20 * 2 ** 20
#: Largest side of the photographs read for the report page.
PICTURE_SOURCE = 480
#: The columns of record.csv, in order.
RECORD_COLUMNS = (*IDENTIFIERS, 'creator', 'created', 'file', 'format', 'units', 'extent_x', 'extent_y',
                  'extent_z', 'pieces', 'container', 'container_size_mm', 'ior_given', 'ior_refined', 'psnr',
                  'steps', 'software', 'commit')


def export_run(run: str, out: str, *, identifiers: dict | None = None, creator: str | None = None,
               watertight: bool = False) -> dict:
    """Write the package of the finished run ``run`` into ``out`` (new or empty); return its
    metadata."""
    folder = RunFolder(run)
    result = folder.read_result() if os.path.isdir(run) else None
    if result is None or result.get('failure'):
        why = 'no result.json' if result is None else f"it failed ({result['failure']})"
        raise ReneusError(f'{run}: not a finished run ({why}); expected the folder of a run that ended with its '
                          'mesh')
    identifiers = check_identifiers(identifiers or {})
    out = guards.check_output_dir(out, inputs=[run], what='package folder')
    name = package_name(identifiers.get('catalogNumber') or os.path.basename(os.path.abspath(run)))
    os.makedirs(out, exist_ok=True)
    mesh = load_mesh(folder.mesh)
    atomic_export(mesh, os.path.join(out, f'{name}.ply'))
    files = {'mesh': f'{name}.ply'}
    if os.path.isfile(folder.web_mesh):
        shutil.copyfile(folder.web_mesh, os.path.join(out, f'{name}.glb'))
        files['web_mesh'] = f'{name}.glb'
        if os.path.getsize(folder.web_mesh) > ACCESS_MAX_BYTES:
            access_faces = decimated_glb(folder.web_mesh, os.path.join(out, f'{name}_access.glb'), ACCESS_MAX_BYTES)
            files['access_mesh'] = f'{name}_access.glb'
    closed = None
    if watertight:
        closed = _watertight(mesh)
        atomic_export(closed.pop('mesh'), os.path.join(out, f'{name}_watertight.ply'))
        files['watertight_mesh'] = f'{name}_watertight.ply'
    config = folder.read_config()
    units = result.get('units')
    created = datetime.datetime.fromtimestamp(os.path.getmtime(folder.result), datetime.timezone.utc)
    dataset = _dataset(config.get('data'))
    metadata = {
        'dwc': identifiers,
        'ac': {'dcterms:format': 'model/gltf-binary' if 'web_mesh' in files else 'application/ply',
               'ac:subtypeLiteral': '3D model', 'ac:resourceCreationTechnique': CREATION_TECHNIQUE,
               'dc:creator': creator, 'xmp:CreateDate': created.isoformat(timespec='seconds'),
               **_terms_3d(mesh, units, dataset)},
        'files': files,
        'mesh': {'units': units or 'the dataset\'s (it states none)', 'frame': result.get('frame'),
                 'extent': np.asarray(mesh.extents).round(4).tolist() if len(mesh.faces) else None,
                 # The specimen's length, width and height (its smallest enclosing box, any turn).
                 'size': (np.sort(mesh.bounding_box_oriented.primitive.extents)[::-1].round(4).tolist()
                          if len(mesh.faces) else None),
                 'vertices': len(mesh.vertices), 'faces': len(mesh.faces), 'pieces': components(mesh),
                 **({'access_faces': access_faces} if 'access_mesh' in files else {}),
                 'watertight': bool(mesh.is_watertight), **({'watertight_variant': closed} if closed else {})},
        'paradata': {
            'capture': _capture(config.get('data')),
            'container': _container(config.get('data'), result),
            'training': {k: result.get(k) for k in ('iterations', 'seconds', 'psnr', 'components',
                                                    'stopped_by_budget', 'refined')},
            'software': {'name': 'reneus-mi', 'version': version('reneus-mi'), 'commit': _commit()},
            'configuration': config,
        },
    }
    atomic_write_text(os.path.join(out, 'metadata.json'), json.dumps(metadata, indent=2, default=float))
    atomic_write_text(os.path.join(out, 'record.csv'), _record(metadata, name))
    write_page(os.path.join(out, f'{name}.html'), metadata, os.path.join(out, f'{name}.ply'),
               os.path.join(out, files.get('access_mesh', files.get('web_mesh'))) if 'web_mesh' in files else None,
               dataset)
    atomic_write_text(os.path.join(out, FIXITY), _fixity(out))
    return metadata


def _fixity(folder: str) -> str:
    """Every file of the package with its SHA-256, as BagIt's manifest lists them (DIGEST, two
    spaces, PATH): what a repository checks a copy against, years on."""
    lines = []
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        if name != FIXITY and os.path.isfile(path):
            with open(path, 'rb') as f:
                lines.append(f'{hashlib.file_digest(f, "sha256").hexdigest()}  {name}')
    return ''.join(line + '\n' for line in lines)


def check_identifiers(identifiers: dict, where: str = '') -> dict:
    """The identifiers given (empty ones left out), each refused by name where it holds a
    control character (a line break would split record.csv's row) or is longer than
    :data:`MAX_IDENTIFIER`."""
    out = {}
    for term, value in identifiers.items():
        if value is None or value == '':
            continue
        value = str(value)
        bad = [c for c in value if ord(c) < 32 or ord(c) == 127]
        if bad:
            raise ReneusError(f'{where}{term}={value!r}: holds the control character {bad[0]!r}; expected one '
                              'line of printable text')
        if len(value) > MAX_IDENTIFIER:
            raise ReneusError(f'{where}{term}: {len(value)} characters; expected at most {MAX_IDENTIFIER}')
        out[term] = value
    return out


def _cell(value):
    """A value as record.csv holds it: text that a spreadsheet would take for a formula is
    quoted with a leading apostrophe, as spreadsheets themselves do (numbers are numbers)."""
    if value is None:
        return ''
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value


def _terms_3d(mesh: trimesh.Trimesh, units: str | None, dataset) -> dict:
    """The master mesh (``NAME.ply``) in the 3D terms that Audiovisual Core's 3D Task Group
    proposes (tdwg/ac#243, staged for rs.tdwg.org as ac_3d_terms.csv and bf_3d_terms.csv,
    2025-12-23; not yet ratified): its resource type, points and faces, whether its vertices carry colours
    ("True" / "False", as the term defines its values), the photographs it was made from
    (None where the dataset is gone) and the unit of its coordinates (None where the run states
    none)."""
    return {'ac:3DResourceType': 'polygonal mesh', 'ac:pointCount': len(mesh.vertices),
            'ac:faceCount': len(mesh.faces), 'ac:colorBoolean': str(mesh.visual.kind == 'vertex'),
            'ac:numberOfImages': len(dataset.names) if dataset is not None else None, 'bf:Unit': units}


def _dataset(data: str | None):
    """The run's dataset, for the page's cameras and photographs (None where it is gone)."""
    if not data or not os.path.isdir(data):
        return None
    try:
        return load_dataset(data, max_size=PICTURE_SOURCE)
    except ReneusError:
        return None


def package_name(text: str) -> str:
    """A catalogue number as a file name (separators and spaces become _)."""
    return ''.join(c if c.isalnum() or c in '.-_' else '_' for c in str(text)).strip('.') or 'specimen'


def _watertight(mesh: trimesh.Trimesh) -> dict:
    """The mesh with each hole closed by a fan of triangles around its centroid, and how many
    were closed (a boundary that touches itself is left open, and counted)."""
    holes = _boundary_loops(mesh)
    vertices, faces = [np.asarray(mesh.vertices)], [np.asarray(mesh.faces)]
    # Each boundary edge as its one face runs it; the fill runs it the other way.
    boundary = mesh.edges[trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)]
    after = {}
    for a, b in boundary:
        after.setdefault(int(a), []).append(int(b))
    seen, count = set(), len(mesh.vertices)
    for start in after:
        if start in seen or len(after[start]) != 1:
            continue
        loop = [start]
        while len(after.get(loop[-1], ())) == 1 and after[loop[-1]][0] not in seen and after[loop[-1]][0] != start:
            loop.append(after[loop[-1]][0])
            seen.add(loop[-1])
        seen.add(start)
        if after.get(loop[-1]) != [start] or len(loop) < 3:
            continue
        centre = np.asarray(mesh.vertices)[loop].mean(axis=0)
        vertices.append(centre[None])
        faces.append(np.array([[b, a, count] for a, b in zip(loop, loop[1:] + loop[:1])]))
        count += 1
    closed = trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)
    if mesh.visual.kind == 'vertex':
        colours = np.asarray(mesh.visual.vertex_colors)
        extra = np.repeat(colours.mean(axis=0, keepdims=True).astype(colours.dtype), count - len(mesh.vertices), 0)
        closed.visual.vertex_colors = np.concatenate([colours, extra])
    left = _boundary_loops(closed)
    return {'mesh': closed, 'holes_closed': holes - left, 'holes_left': left, 'watertight': bool(closed.is_watertight)}


def _boundary_loops(mesh: trimesh.Trimesh) -> int:
    """The number of holes: connected chains of edges that only one face has."""
    if len(mesh.faces) == 0:
        return 0
    edges = mesh.edges_sorted[trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)]
    return len(trimesh.graph.connected_components(edges, min_len=1)) if len(edges) else 0


def _capture(data: str | None) -> dict | None:
    """What the capture command recorded about the photographs (None: not a capture)."""
    report = read_json(os.path.join(data, 'report.json')) if data else None
    if report is None:
        return None
    camera = report['camera']
    transforms = read_json(os.path.join(data, 'transforms.json')) or {}
    return {'camera': camera.get('exif', {}), 'photographs': len(report['views']),
            'left_out': report.get('left_out', {}), 'photo_size': camera['photo_size'],
            'intrinsics_px': camera['K_photo'], 'intrinsics_std_px': camera.get('K_photo_std_px'),
            'pixel_convention': camera.get('pixel_convention'), 'distortion': camera['distortion'],
            'reprojection_rms_px': camera['rms_px'], 'coverage': camera.get('coverage'),
            'board': transforms.get('capture', {}).get('board'), 'container_residual_px':
            report['container']['residual_px'], 'light': report.get('light')}


def _container(data: str | None, result: dict) -> dict | None:
    """The container as the dataset gave it and as the run refined it."""
    meta = read_json(os.path.join(data, 'transforms.json')) if data else None
    if meta is None:
        return None
    report = read_json(os.path.join(data, 'report.json')) or {}
    given = report.get('container', {})
    refined = result.get('refined') or {}
    # A jar's liquid: the capture's report says it; any dataset states it as its innermost interface.
    interfaces = meta.get('containers') or []
    inner = interfaces[-1].get('int_ior') if len(interfaces) > 1 and isinstance(interfaces[-1], dict) else None
    liquid = given.get('liquid_ior') or (inner if isinstance(inner, (int, float)) and inner > 1.0 else None)
    return {'shape': given.get('shape'), 'size_mm': given.get('size_mm'), 'wall_mm': given.get('wall_mm'),
            'wall_refined': refined.get('container.wall'), 'edge_mm': given.get('edge_mm'),
            'edge_measured': given.get('edge_measured'), 'bow_measured': refined.get('container.bow'),
            'pose': given.get('pose'), 'ior_given': meta.get('IOR'), 'ior_refined': refined.get('container.eta'),
            'liquid_ior_given': liquid, 'liquid_ior_refined': refined.get('container.inner_ior'),
            'absorption_given': meta.get('absorption'), 'absorption_refined': refined.get('container.sigma_a'),
            'refined_spread': result.get('refined_spread')}


def _commit() -> str | None:
    """The git commit of the installed package, when it is a checkout."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    try:
        out = subprocess.run(['git', '-C', root, 'rev-parse', 'HEAD'], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return (out.stdout.strip() or None) if out.returncode == 0 else None


def _record(metadata: dict, name: str) -> str:
    mesh, para = metadata['mesh'], metadata['paradata']
    container = para['container'] or {}
    extent = mesh['extent'] or [None] * 3
    row = {**metadata['dwc'], 'creator': metadata['ac']['dc:creator'], 'created': metadata['ac']['xmp:CreateDate'],
           'file': metadata['files'].get('web_mesh', metadata['files']['mesh']),
           'format': metadata['ac']['dcterms:format'], 'units': mesh['units'],
           'extent_x': extent[0], 'extent_y': extent[1], 'extent_z': extent[2], 'pieces': mesh['pieces'],
           'container': container.get('shape'),
           'container_size_mm': 'x'.join(f'{v:g}' for v in container['size_mm']) if container.get('size_mm') else None,
           'ior_given': container.get('ior_given'), 'ior_refined': container.get('ior_refined'),
           'psnr': para['training']['psnr'], 'steps': para['training']['iterations'],
           'software': f"reneus-mi {para['software']['version']}", 'commit': para['software']['commit']}
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=RECORD_COLUMNS, lineterminator='\n')
    writer.writeheader()
    writer.writerow({k: _cell(v) for k, v in row.items()})
    return text.getvalue()
