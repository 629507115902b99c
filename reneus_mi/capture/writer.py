"""What the capture command writes: a dataset the rest of reneus-mi reads, and its checks.

Layout of ``DATASET_DIR`` (coordinates: the board's frame, millimetres)::

    transforms.json      NeRF/nerfstudio cameras (pinhole: the photographs are undistorted),
                         the ReNeuS keys (IOR, mesh_outside), "ambient" (C_out, linear RGB), and
                         "capture": the board (pattern file, size, pose in the world, measured
                         white and black print), each frame's exposure gain (already applied)
                         and photograph, the lens, the container's place; written last
    images/NAME.png      of each photograph the window around the container (one size for all,
                         each with its own cx, cy: :mod:`reneus_mi.capture.crops`),
                         undistorted, at the dataset's scale, exposures normalised
    container.ply        the container in the board's frame
    container_inner.ply  a hollow container's inside (``--wall-mm``): the air of a case, the
                         liquid of a jar; transforms.json's "containers" names both
    board.png            the printed pattern (BOARD_PX_PER_MM pixels per millimetre)
    report.json          calibration and registration figures, per view; views left out
    overlays/NAME.jpg    pictures to check (see :mod:`reneus_mi.capture.overlay`)

The masks are not written: the loader projects the registered container, as the paper did.
"""
from __future__ import annotations

import json
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from tqdm import tqdm

from reneus_mi.capture import overlay
from reneus_mi.capture.charuco import Board
from reneus_mi.capture.calibrate import Calibration, Coverage
from reneus_mi.capture.crops import CroppedViews
from reneus_mi.capture.photos import WORKERS
from reneus_mi.capture.placement import interfaces, local_mesh
from reneus_mi.capture.settings import CaptureSettings, to_json
from reneus_mi.data.cameras import OPENGL_FROM_OPENCV
from reneus_mi.data.dataset import containers_json
from reneus_mi.data.images import write_image
from reneus_mi.data.undistort import opencv_K
from reneus_mi.geometry.shapes import write_container
from reneus_mi.utils.io import atomic_write_text

#: Names the command writes into the dataset folder (a rerun after a refusal may replace them).
OUTPUTS = ('transforms.json', 'images', 'container.ply', 'container_inner.ply', 'board.png', 'report.json',
           'overlays')
#: Resolution of the written board pattern.
BOARD_PX_PER_MM = 10.0
#: Where a pixel's centre is, for every intrinsic matrix written (report.json, transforms.json).
PIXEL_CONVENTION = ('the centre of the top-left pixel is at (0.5, 0.5), as in Mitsuba, COLMAP and nerfstudio; '
                    "OpenCV puts it at (0, 0): K_photo_opencv is K_photo with cx, cy 0.5 px less")
#: Words for the frame, said once.
FRAME = ('board (OpenCV ChArUco: origin at the outer corner of the first square, x along the '
         'columns, y along the rows, z into the table), millimetres')


def _stem(name: str) -> str:
    return os.path.splitext(name)[0]


def write_views(out: str, names: list[str], images: Sequence[np.ndarray], K: np.ndarray, c2w: np.ndarray,
                meta: dict, frames: list[dict] | None = None) -> None:
    """``images/NAME.png`` (RGB: the masks are the container's projection, not measured) and
    ``transforms.json`` (written last) with the pinhole cameras, ``meta``'s keys and each
    frame's extra keys. ``K`` is one (3,3) for all views or (N,3,3); ``images`` of one size,
    made as they are asked for (:class:`~reneus_mi.capture.crops.CroppedViews`), by
    :data:`~reneus_mi.capture.photos.WORKERS` at a time."""
    os.makedirs(os.path.join(out, 'images'), exist_ok=True)

    def one(i):
        image = images[i]
        write_image(os.path.join(out, 'images', _stem(names[i]) + '.png'), image)
        return image.shape[:2]
    with ThreadPoolExecutor(WORKERS) as pool:
        shapes = list(tqdm(pool.map(one, range(len(names))), total=len(names), desc='write the dataset',
                           unit='image', disable=None, leave=False))
    h, w = shapes[0]

    def camera(k):
        return {'fl_x': k[0, 0], 'fl_y': k[1, 1], 'cx': k[0, 2], 'cy': k[1, 2]}
    shared = K.ndim == 2
    top = {'camera_model': 'PINHOLE', 'w': w, 'h': h, **(camera(K) if shared else {})}
    entries = []
    for i, name in enumerate(names):
        entry = {'file_path': f'images/{_stem(name)}.png', 'transform_matrix': (c2w[i] @ OPENGL_FROM_OPENCV).tolist()}
        if not shared:
            entry.update(camera(K[i]))
        entry.update(frames[i] if frames else {})
        entries.append(entry)
    atomic_write_text(os.path.join(out, 'transforms.json'),
                      json.dumps({**top, **meta, 'frames': entries}, indent=2, default=float))


def write(out: str, s: CaptureSettings, board: Board, cal: Calibration, K: np.ndarray, frame: tuple[int, int],
          views: CroppedViews, reg, light, left_out: dict[str, str], cover: Coverage, exif: dict, *,
          given: CaptureSettings | None = None) -> dict:
    """Write the dataset into ``out`` (checked by the caller); return the report. ``K``,
    ``frame``: the dataset's pinhole camera and (width, height) before the views are cropped to
    their windows; ``left_out``: every photograph left out, in whichever pass, with its reason;
    ``exif``: the camera as the photographs' EXIF states it; ``given``: the settings as stated,
    where ``s`` has the size measured in place of ``auto``."""
    w, h = frame
    windows = views.windows
    placed = interfaces(s.container, s.size_mm, s.ior, s.wall_mm, s.liquid_ior, reg.pose, s.edge_mm)
    for interface, mesh in placed:
        write_container(mesh, os.path.join(out, interface.mesh), normals=s.container != 'box')
    write_image(os.path.join(out, 'board.png'), board.pattern(BOARD_PX_PER_MM).astype(np.float32) / 255.0)
    report = {
        'frame': FRAME,
        'settings': to_json(given or s),
        'camera': {'pixel_convention': PIXEL_CONVENTION, 'exif': exif,
                   'K_photo': cal.K.tolist(), 'K_photo_opencv': opencv_K(cal.K).tolist(),
                   'K_photo_std_px': dict(zip(('f', 'cx', 'cy'), cal.K_std.tolist())),
                   'distortion': dict(zip(('k1', 'k2', 'p1', 'p2', 'k3'), cal.dist.tolist())),
                   'photo_size': [cal.width, cal.height], 'K': K.tolist(), 'size': [w, h],
                   'rms_px': cal.rms,
                   'coverage': {'share': cover.share, 'extrapolated_px': cover.extrapolated_px,
                                'worst_at_px': list(cover.worst), 'hull_px': cover.hull.round(1).tolist(),
                                'crop_px': None if cover.crop is None else list(cover.crop)}},
        'views': [{'photo': v.name, 'corners_found': int(len(v.ids)), 'corners_used': int(v.used.sum()),
                   'rms_px': v.rms, 'rotation_std_deg': v.rotation_std_deg,
                   'translation_std_mm': v.translation_std_mm, 'c2w': v.c2w.tolist(), 'exposure_gain': float(g),
                   'container_residual_px': float(r), 'window_px': [*map(int, corner), *windows.size]}
                  for v, g, r, corner in zip(cal.views, light.gains, reg.view_residuals, windows.corners)],
        'left_out': left_out,
        'container': {'shape': s.container, 'size_mm': list(s.size_mm), 'edge_mm': s.edge_mm, 'wall_mm': s.wall_mm,
                      'liquid_ior': s.liquid_ior, 'pose': list(reg.pose),
                      'pose_given': s.container_pose is not None, 'residual_px': reg.residual,
                      'size_measured': reg.size_measured,
                      'size_fit_mm': None if reg.best_size is None else list(reg.best_size),
                      'size_fit_std_mm': None if reg.size_std is None else list(reg.size_std),
                      'size_fit_outline_px': None if reg.size_residuals is None else
                      dict(zip(('stated', 'fit'), reg.size_residuals)),
                      'edge_measured': reg.edge_mm is not None,
                      'edge_fit_outline_px': None if reg.edge_residuals is None else
                      dict(zip(('sharp', 'rounded'), reg.edge_residuals))},
        'light': {'ambient': light.ambient.tolist(), 'ambient_from': light.ambient_from,
                  'board_white': light.white.tolist(), 'board_black': light.black.tolist()},
    }
    atomic_write_text(os.path.join(out, 'report.json'), json.dumps(report, indent=2))
    meta = {
        'IOR': s.ior, 'mesh_outside': 'container.ply',
        **({'containers': containers_json(placed[0][0], [i for i, _ in placed[1:]])} if len(placed) > 1 else {}),
        'ambient': light.ambient.tolist(),
        'capture': {
            'frame': FRAME, 'units': 'mm',
            'board': {'pattern': 'board.png', 'px_per_mm': BOARD_PX_PER_MM, 'squares': [board.columns, board.rows],
                      'square_mm': board.square_mm, 'marker_mm': board.marker_mm, 'dictionary': board.dictionary,
                      'size_mm': list(board.size_mm), 'to_world': np.eye(4).tolist(),
                      'white': light.white.tolist(), 'black': light.black.tolist()},
            'container': report['container'],
            'exposure': 'each frame\'s exposure_gain (relative to the darkest photograph) is divided out of its image',
        },
    }
    Ks = np.stack([windows.K(K, v) for v in range(len(views))])
    write_views(out, [v.name for v in cal.views], views, Ks, np.stack([v.c2w for v in cal.views]), meta,
                [{'photo': v.name, 'exposure_gain': float(g)} for v, g in zip(cal.views, light.gains)])
    return report


def write_overlays(out: str, images, K, c2w, board: Board, cal: Calibration, s: CaptureSettings, *,
                   measured=None, pose=None, residuals=None) -> None:
    """One overlay per photograph into ``out/overlays``."""
    segments = [segment for inset in ((0.0,) if s.wall_mm is None else (0.0, s.wall_mm))
                for segment in overlay.wireframe(s.container, local_mesh(s.container, s.size_mm, inset, s.edge_mm))]
    for i, view in enumerate(tqdm(cal.views, desc='overlays', unit='photo', disable=None, leave=False)):
        text = f'{view.name}: {int(view.used.sum())} corners, RMS {view.rms:.2f} px'
        if residuals is not None and np.isfinite(residuals[i]):
            text += f', container {residuals[i]:.2f} px'
        picture = overlay.draw(images[i], K, c2w[i], board, ids=view.ids, pixels=view.pixels, used=view.used,
                               lens=(cal.K, cal.dist), segments=segments, pose=pose,
                               measured=None if measured is None else measured[i], text=text)
        overlay.write(os.path.join(out, 'overlays', _stem(view.name) + '.jpg'), picture)


def table(report: dict) -> str:
    """The per-view table the command prints."""
    lines = [f"{'photograph':<24} {'corners':>8} {'used':>5} {'RMS px':>7} {'sd deg':>7} {'sd mm':>6} {'gain':>6} "
             f"{'container px':>12}"]
    for v in report['views']:
        lines.append(f"{v['photo']:<24} {v['corners_found']:>8} {v['corners_used']:>5} {v['rms_px']:>7.3f} "
                     f"{v['rotation_std_deg']:>7.3f} {v['translation_std_mm']:>6.3f} "
                     f"{v['exposure_gain']:>6.3f} {v['container_residual_px']:>12.2f}")
    for name, reason in report['left_out'].items():
        lines.append(f'{name:<24} left out: {reason}')
    cam = report['camera']
    d = cam['distortion']
    sd = cam['K_photo_std_px']
    lines.append(f"camera: f {cam['K_photo'][0][0]:.2f} ± {sd['f']:.2f} px, principal point "
                 f"({cam['K_photo'][0][2]:.2f} ± {sd['cx']:.2f}, {cam['K_photo'][1][2]:.2f} ± {sd['cy']:.2f}; "
                 f"top-left pixel's centre at 0.5), k1 {d['k1']:.4f} k2 {d['k2']:.4f} p1 {d['p1']:.5f} "
                 f"p2 {d['p2']:.5f} k3 {d['k3']:.4f}, RMS {cam['rms_px']:.3f} px")
    box = report['container']
    if box['size_fit_mm']:
        fit = ' x '.join(f'{v:.2f} ± {e:.2f}' for v, e in zip(box['size_fit_mm'], box['size_fit_std_mm']))
        said = ('measured (--size-mm auto)' if box['size_measured'] else
                f"stated {'x'.join(f'{v:g}' for v in box['size_mm'])} mm")
        lines.append(f"container: {said}; the photographs fit {fit} mm (statistical deviations)")
    if box['edge_measured']:
        px = box['edge_fit_outline_px']
        lines.append(f"container: stated as a box, its edges rounded in the photographs: radius {box['edge_mm']:g} mm "
                     f"(outline {px['sharp']:.2f} px from the silhouettes as a box, {px['rounded']:.2f} px rounded)")
    cover = cam['coverage']
    lines.append(f"board coverage: {cover['share']:.0%} of the frame; the lens model uncertain by up to "
                 f"{cover['extrapolated_px']:.2f} px beyond it")
    light = report['light']
    lines.append(f"light: C_out {np.round(light['ambient'], 4).tolist()} (from the {light['ambient_from']}), "
                 f"white print {np.round(light['board_white'], 4).tolist()}")
    return '\n'.join(lines)
