"""A specimen's report page: one self-contained HTML file a curator opens from disk.

Everything is inside the file (no network, no file beside it): the ``<model-viewer>`` web
component (vendored, ``reneus_mi/export/vendor/model-viewer``), the mesh's GLB, and the pictures as
data URIs. The page holds an interactive 3D view of the mesh with a scale bar in
millimetres (or the dataset's units) that follows the zoom, a turntable of clay renders,
photographs beside the mesh rendered from the same cameras, the capture's overlays, and the
figures of the package's ``metadata.json`` (:mod:`reneus_mi.export.package`).

When the viewer has shown the model the page sets ``data-state="loaded"`` on its body; errors
it meets are listed in ``data-errors`` (what a browser test reads).
"""
from __future__ import annotations

import base64
import html
import json
import os
import tempfile

import numpy as np

from reneus_mi.data.images import resize, write_image
from reneus_mi.geometry.mesh import load_mesh
from reneus_mi.render.preview import render_preview, render_view
from reneus_mi.utils.io import atomic_write_text

#: The vendored web component.
MODEL_VIEWER = os.path.join(os.path.dirname(__file__), 'vendor', 'model-viewer', 'model-viewer-umd.min.js')
#: Clay renders around the mesh, and photographs shown beside the mesh from their camera.
TURNTABLE, PAIRS = 8, 3
#: First in the page: every error and console error is noted in the body's data-errors.
_ERRORS = """
const pageErrors = [];
function noteError(text) { pageErrors.push(text); if (document.body) document.body.dataset.errors = pageErrors.join(' | '); }
const consoleError = console.error.bind(console);
console.error = (...args) => { noteError(args.map(String).join(' ')); consoleError(...args); };
window.addEventListener('error', (e) => noteError(String(e.message)));
window.addEventListener('unhandledrejection', (e) => noteError('unhandled: ' + String(e.reason)));
"""
#: Side of the pictures on the page, pixels, and the renders' samples per pixel.
PICTURE, SPP = 240, 64

_SCALE_BAR = """
const viewer = document.getElementById('model');
const bar = document.getElementById('bar'), label = document.getElementById('bar-label');
const unitsPerMetre = UNITS_PER_METRE, unit = UNIT;
function scaleBar() {
  // Pixels per metre at the orbit's centre: the canvas height spans 2 r tan(fov / 2).
  const r = viewer.getCameraOrbit().radius, fov = viewer.getFieldOfView() * Math.PI / 180;
  const perUnit = viewer.clientHeight / (2 * r * Math.tan(fov / 2)) / unitsPerMetre;
  // The round length (1, 2 or 5 times a power of ten) nearest to 120 pixels.
  const p = Math.pow(10, Math.floor(Math.log10(120 / perUnit)));
  const length = [p, 2 * p, 5 * p, 10 * p].reduce((a, b) => Math.abs(b * perUnit - 120) < Math.abs(a * perUnit - 120) ? b : a);
  bar.style.width = (length * perUnit).toFixed(1) + 'px';
  label.textContent = (+length.toPrecision(3)) + ' ' + unit;
}
viewer.addEventListener('error', (e) => noteError('model-viewer: ' + JSON.stringify(e.detail)));
viewer.addEventListener('camera-change', scaleBar);
viewer.addEventListener('load', () => { scaleBar(); document.body.dataset.state = 'loaded'; });
"""

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 0 auto; max-width: 1100px; padding: 1em; color: #222; background: #f4f4f2; }
h1 { font-size: 1.4em; margin: 0.2em 0; } h2 { font-size: 1.1em; margin-top: 1.5em; }
.viewer { position: relative; }
model-viewer { width: 100%; height: 520px; background: #2b2f36; border-radius: 6px; }
.scale { position: absolute; left: 16px; bottom: 16px; color: #fff; font-size: 0.9em; }
#bar { height: 6px; background: #fff; border: 1px solid #000; margin-bottom: 3px; }
.pictures { display: flex; flex-wrap: wrap; gap: 6px; }
.pictures figure { margin: 0; } .pictures img { width: PICTUREpx; border-radius: 3px; }
figcaption { font-size: 0.8em; color: #555; }
table { border-collapse: collapse; } td, th { text-align: left; padding: 2px 10px 2px 0; vertical-align: top; }
th { font-weight: 600; color: #444; }
""".replace('PICTURE', str(PICTURE))


def write_page(out: str, metadata: dict, mesh_path: str, glb_path: str | None, dataset=None) -> str:
    """Write the report page ``out`` of a package (``metadata`` as :func:`~reneus_mi.export.package.export_run`
    makes it, the mesh and its GLB); ``dataset`` (a :class:`~reneus_mi.data.dataset.Dataset`,
    optional) gives the cameras of the turntable's axis and the photographs."""
    title = metadata['dwc'].get('catalogNumber') or os.path.splitext(os.path.basename(mesh_path))[0]
    units = metadata['mesh'].get('units')
    with tempfile.TemporaryDirectory() as tmp:
        turntable = _turntable(mesh_path, dataset, tmp)
        pairs = _pairs(mesh_path, dataset, tmp) if dataset is not None else []
    overlays = _overlays(dataset)
    viewer = ''
    if glb_path:
        with open(glb_path, 'rb') as f:
            glb = base64.b64encode(f.read()).decode()
        with open(MODEL_VIEWER) as f:
            component = f.read()
        script = (_SCALE_BAR.replace('UNITS_PER_METRE', '1000.0' if units == 'mm' else '1.0')
                  .replace('UNIT', json.dumps('mm' if units == 'mm' else 'units')))
        viewer = (f'<script>{component}</script>\n<div class="viewer"><model-viewer id="model" '
                  f'src="data:model/gltf-binary;base64,{glb}" camera-controls auto-rotate shadow-intensity="0.6" '
                  f'exposure="1.1" alt="{html.escape(title)}"></model-viewer><div class="scale"><div id="bar"></div>'
                  f'<span id="bar-label"></span></div></div>\n<script>{script}</script>')
    body = [f'<h1>{html.escape(title)}</h1>', _identifiers(metadata), viewer,
            '<h2>Turntable</h2>', _pictures(turntable)]
    if pairs:
        body += ['<h2>Photographs and the model from the same cameras</h2>', _pictures(pairs)]
    if overlays:
        body += ['<h2>Capture overlays</h2>', _pictures(overlays)]
    body += ['<h2>Figures</h2>', _figures(metadata)]
    page = (f'<!doctype html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            f'<style>{_STYLE}</style><script>{_ERRORS}</script></head>\n<body data-state="loading" data-errors="">\n'
            + '\n'.join(body)
            + '\n</body></html>\n')
    atomic_write_text(out, page)
    return out


def _image_uri(path: str, mime: str = 'image/png') -> str:
    with open(path, 'rb') as f:
        return f'data:{mime};base64,{base64.b64encode(f.read()).decode()}'


def _turntable(mesh_path: str, dataset, tmp: str) -> list[tuple[str, str]]:
    """Clay renders every 360/TURNTABLE degrees about the vertical: the first camera's up, its
    direction turned about it."""
    if dataset is not None:
        c2w = dataset.c2w[0]
        up, start = -c2w[:3, 1], c2w[:3, 3] - load_mesh(mesh_path).bounds.mean(axis=0)
    else:
        up, start = np.array([0.0, 0.0, 1.0]), np.array([1.0, -1.0, 0.8])
    up = up / np.linalg.norm(up)
    out = []
    for k in range(TURNTABLE):
        angle = 2 * np.pi * k / TURNTABLE
        d = _rotate(start, up, angle)
        path = os.path.join(tmp, f'turn_{k}.png')
        render_preview(mesh_path, path, direction=d, up=up, size=PICTURE, spp=SPP)
        out.append((_image_uri(path), f'{360 * k // TURNTABLE} degrees'))
    return out


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation of ``v`` about the unit ``axis``."""
    return (v * np.cos(angle) + np.cross(axis, v) * np.sin(angle) + axis * np.dot(axis, v) * (1 - np.cos(angle)))


def _pairs(mesh_path: str, dataset, tmp: str) -> list[tuple[str, str]]:
    """PAIRS photographs spread over the dataset, each beside the mesh rendered by its camera
    through the container (the specimen at the same place and size), both cropped to the
    container's projection (its mask) with a margin."""
    n = len(dataset.names)
    out = []
    for i in sorted({int(round(x)) for x in np.linspace(0, n - 1, PAIRS)}):
        (x0, y0, x1, y1), K = _window(dataset.masks[i]), dataset.K[i]
        scale = PICTURE / max(x1 - x0, y1 - y0)
        size = (max(1, int(round((x1 - x0) * scale))), max(1, int(round((y1 - y0) * scale))))
        photo = os.path.join(tmp, f'photo_{i}.png')
        write_image(photo, resize(dataset.image(i)[y0:y1, x0:x1], size))
        # The window's camera: the same rays, its pixels scaled and shifted.
        K_window = np.array([[K[0, 0] * scale, 0.0, (K[0, 2] - x0) * scale],
                             [0.0, K[1, 1] * scale, (K[1, 2] - y0) * scale], [0.0, 0.0, 1.0]])
        render = os.path.join(tmp, f'view_{i}.png')
        render_view(mesh_path, render, K_window, dataset.c2w[i], size, spp=SPP, through=_interfaces(dataset))
        out += [(_image_uri(photo), f'{dataset.names[i]}: photograph'), (_image_uri(render), f'{dataset.names[i]}: model')]
    return out


def _interfaces(dataset) -> list[tuple[str, float]]:
    """The dataset's container as (mesh file, IOR inside), outermost first (none: no container)."""
    if dataset.container is None:
        return []
    return [(dataset.container, dataset.ior)] + [(layer.mesh, layer.ior) for layer in dataset.inner]


def _window(mask: np.ndarray, margin: float = 0.15) -> tuple[int, int, int, int]:
    """The bounding box of a mask grown by ``margin`` of its size each way, within the image
    (the whole image for an empty mask): x0, y0, x1, y1."""
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return 0, 0, w, h
    grow = margin * max(xs.max() - xs.min(), ys.max() - ys.min())
    return (max(0, int(xs.min() - grow)), max(0, int(ys.min() - grow)),
            min(w, int(xs.max() + 1 + grow)), min(h, int(ys.max() + 1 + grow)))


def _overlays(dataset) -> list[tuple[str, str]]:
    """Up to PAIRS of the capture's overlays (a capture's dataset only)."""
    folder = os.path.join(dataset.root, 'overlays') if dataset is not None else None
    if folder is None or not os.path.isdir(folder):
        return []
    names = sorted(os.listdir(folder))
    chosen = [names[int(round(x))] for x in np.linspace(0, len(names) - 1, min(PAIRS, len(names)))] if names else []
    return [(_image_uri(os.path.join(folder, name), 'image/jpeg'), name) for name in dict.fromkeys(chosen)]


def _pictures(items: list[tuple[str, str]]) -> str:
    return '<div class="pictures">' + ''.join(
        f'<figure><img src="{uri}" alt="{html.escape(caption)}"><figcaption>{html.escape(caption)}</figcaption>'
        f'</figure>' for uri, caption in items) + '</div>'


def _identifiers(metadata: dict) -> str:
    ids = metadata['dwc']
    return '<p>' + ' · '.join(f'{html.escape(k)}: <b>{html.escape(str(v))}</b>' for k, v in ids.items()) + '</p>' \
        if ids else ''


def _figures(metadata: dict) -> str:
    mesh, para = metadata['mesh'], metadata['paradata']
    training, container, capture = para['training'], para['container'] or {}, para['capture'] or {}
    rows = [('units', mesh['units']),
            ('extent', None if mesh['extent'] is None else ' x '.join(f'{v:g}' for v in mesh['extent'])),
            ('pieces', mesh['pieces']), ('watertight', mesh['watertight']),
            ('steps', training.get('iterations')),
            ('PSNR (dB)', None if training.get('psnr') is None else f"{training['psnr']:.2f}"),
            ('container', container.get('shape')),
            ('container size (mm)', None if not container.get('size_mm') else
             ' x '.join(f'{v:g}' for v in container['size_mm'])),
            ('IOR given / refined', f"{container.get('ior_given')} / {container.get('ior_refined')}"),
            ('camera', ' '.join(str(capture.get('camera', {}).get(k, '')) for k in ('make', 'model', 'lens')).strip()
             or None),
            ('photographs used', capture.get('photographs')),
            ('reprojection RMS (px)', capture.get('reprojection_rms_px')),
            ('board coverage', None if not capture.get('coverage') else
             f"{capture['coverage']['share']:.0%} of the frame, lens uncertain by up to "
             f"{capture['coverage']['extrapolated_px']:.1f} px beyond it"),
            ('software', f"reneus-mi {para['software']['version']} ({para['software']['commit'] or 'no commit'})"),
            ('made by', metadata['ac'].get('dc:creator')), ('date', metadata['ac'].get('xmp:CreateDate'))]
    return '<table>' + ''.join(f'<tr><th>{html.escape(k)}</th><td>{html.escape(str(v))}</td></tr>'
                               for k, v in rows if v not in (None, '', 'None / None')) + '</table>'
