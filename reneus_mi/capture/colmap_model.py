"""Poses from a COLMAP sparse model instead of a board.

When the photographs were posed by structure from motion on their surroundings, COLMAP's
sparse model (``cameras``, ``images``, read by ``pycolmap``, text or binary) gives each
photograph's camera. The container is a mesh given in that model's frame (its units are the
model's). Cameras of COLMAP's pinhole and OpenCV families (SIMPLE_PINHOLE, PINHOLE,
SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV without its rational terms) are undistorted by
:func:`reneus_mi.data.undistort.undistort` to pinhole cameras. COLMAP's pixel convention
is reneus-mi's (the top-left pixel's centre at (0.5, 0.5)) and its cameras have OpenCV's
axes, so poses are taken as they are: ``c2w = cam_from_world⁻¹``. As the capture's, the
dataset keeps of each photograph the window around the container
(:mod:`reneus_mi.capture.crops`).

The command (:mod:`reneus_mi.colmap`)::

    python -m reneus_mi.colmap SPARSE_DIR --images IMAGES_DIR --container MESH --ior 1.5 \\
        -o DATASET_DIR [--max-size N | --downscale F]
"""
from __future__ import annotations

import os
import shutil

import numpy as np

from reneus_mi.capture import photos
from reneus_mi.capture.crops import CroppedViews, container_windows
from reneus_mi.capture.writer import write_views
from reneus_mi.data.checks import check_ior
from reneus_mi.data.undistort import distortion, output_size, pinhole_K
from reneus_mi.geometry.container import load_container, mesh_type
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError


def _lens(camera, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(K, distortion k1 k2 p1 p2 k3) of a pycolmap camera."""
    model = camera.model.name if hasattr(camera.model, 'name') else str(camera.model)
    p = [float(x) for x in camera.params]
    if model == 'SIMPLE_PINHOLE':
        f, cx, cy = p
        fx = fy = f
        d = []
    elif model == 'PINHOLE':
        fx, fy, cx, cy = p
        d = []
    elif model == 'SIMPLE_RADIAL':
        f, cx, cy, k = p
        fx = fy = f
        d = [k]
    elif model == 'RADIAL':
        f, cx, cy, k1, k2 = p
        fx = fy = f
        d = [k1, k2]
    elif model == 'OPENCV':
        fx, fy, cx, cy, *d = p
    elif model == 'FULL_OPENCV':
        fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6 = p
        if any((k4, k5, k6)):
            raise ReneusError(f'{where}: FULL_OPENCV camera with rational terms k4-k6 {[k4, k5, k6]}; '
                              'expected them zero (OpenCV\'s k1, k2, p1, p2, k3 model)')
        d = [k1, k2, p1, p2, k3]
    else:
        raise ReneusError(f'{where}: camera model {model}; expected SIMPLE_PINHOLE, PINHOLE, '
                          'SIMPLE_RADIAL, RADIAL, OPENCV or FULL_OPENCV (undistort with COLMAP first)')
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return K, distortion(d, where)


def read_model(sparse: str):
    """The pycolmap reconstruction in folder ``sparse``, or one line saying why not."""
    try:
        import pycolmap
    except ImportError:
        raise ReneusError('reading a COLMAP model needs pycolmap: pip install -e ".[colmap]"') from None
    if not os.path.isdir(sparse) or not any(os.path.isfile(os.path.join(sparse, f'cameras.{e}'))
                                            for e in ('bin', 'txt')):
        raise ReneusError(f'{sparse}: expected a COLMAP sparse model folder (cameras, images, points3D '
                          '.bin or .txt)')
    try:
        return pycolmap.Reconstruction(sparse)
    except Exception as e:  # pycolmap raises its own kinds
        raise ReneusError(f'{sparse}: unreadable COLMAP model ({type(e).__name__}: {e})') from None


def convert(sparse: str, images_dir: str, container: str, ior: float, out: str, *,
            max_size: int | None = None, downscale: float | None = None) -> int:
    """Write a dataset from a COLMAP model; returns the number of views."""
    out = guards.check_output_dir(out, inputs=[sparse, images_dir, container], what='dataset folder')
    mesh_type(container)
    mesh = load_container(container)
    check_ior(ior, '--ior')
    model = read_model(sparse)
    views = sorted((im for im in model.images.values() if im.has_pose), key=lambda im: im.name)
    if not views:
        raise ReneusError(f'{sparse}: the model has no posed image')
    names, files, lenses, c2ws, size = [], [], [], [], None
    for im in views:
        path = os.path.join(images_dir, im.name)
        if not os.path.isfile(path):
            raise ReneusError(f'{path}: photograph of the COLMAP model\'s image {im.name!r} is missing')
        camera = model.cameras[im.camera_id]
        here = (camera.width, camera.height)
        if size is None:
            size = here
        elif here != size:
            raise ReneusError(f'{sparse}: camera {im.camera_id} is {here[0]}x{here[1]}, another {size[0]}x{size[1]}; '
                              'expected one image size')
        stored = photos.header(path).stored
        if stored != here:
            raise ReneusError(f'{path}: is {stored[0]}x{stored[1]}, but its COLMAP camera is {here[0]}x{here[1]}')
        pose = im.cam_from_world() if callable(im.cam_from_world) else im.cam_from_world
        w2c = np.eye(4)
        w2c[:3] = np.asarray(pose.matrix(), np.float64)
        names.append(os.path.basename(im.name))
        files.append(path)
        lenses.append(_lens(camera, f'{sparse}: camera {im.camera_id}'))
        c2ws.append(np.linalg.inv(w2c))
    if len(set(names)) != len(names):
        raise ReneusError(f'{sparse}: image names repeat once their folders are dropped; expected distinct names')
    width, height, scale = output_size(*size, max_size=max_size, downscale=downscale)
    K_frame = np.stack([pinhole_K(K, scale) for K, _ in lenses])
    hull = np.asarray(mesh.convex_hull.vertices)
    windows = container_windows(hull, K_frame, np.stack(c2ws), (width, height))
    photos.check_memory(len(files), size, windows.size, workers=photos.WORKERS)

    def lens_of(v):
        return (photos.decode(photos.header(files[v])), *lenses[v])
    os.makedirs(out, exist_ok=True)
    name = 'container' + os.path.splitext(container)[1].lower()
    shutil.copyfile(container, os.path.join(out, name))
    write_views(out, names, CroppedViews(windows, K_frame, lens_of),
                np.stack([windows.K(K_frame, v) for v in range(len(names))]), np.stack(c2ws),
                {'IOR': float(ior), 'mesh_outside': name, 'source': f'COLMAP model {os.path.abspath(sparse)}'},
                [{'photo': os.path.basename(f)} for f in files])
    return len(names)
