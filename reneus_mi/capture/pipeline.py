"""From a folder of photographs to a dataset: :func:`run`, the pipeline of ``python -m
reneus_mi.capture PHOTOS -o DATASET`` (:mod:`reneus_mi.capture.__main__`) and of a batch's
capture folders.

1. Find the board in every photograph (:mod:`~reneus_mi.capture.board`); refuse, in one line,
   a capture where no photograph shows it, or shows another dictionary or layout.
2. Calibrate (:mod:`~reneus_mi.capture.calibrate`), leaving out photographs that cannot take part.
3. Undistort every photograph to the dataset's pinhole camera, scaled by ``--max-size`` or
   ``--downscale`` (:mod:`~reneus_mi.data.undistort`; memory checked first).
4. Find the container (:mod:`~reneus_mi.capture.register`), or take ``--container-pose``.
5. Calibrate again without the corners seen through the container, undistort again, refine
   the container's place from the first one.
6. Measure each photograph's exposure, C_out and the print's brightness
   (:mod:`~reneus_mi.capture.exposure`) and normalise the exposures.
7. Write an overlay per photograph, then the dataset (:mod:`~reneus_mi.capture.export`;
   its ``transforms.json`` last: a folder that has one holds the whole dataset).
"""
from __future__ import annotations

import os
import time
import warnings

import cv2
import numpy as np

from reneus_mi.capture import board as board_mod
from reneus_mi.capture import export, photos, settings as settings_mod
from reneus_mi.capture.board import Board
from reneus_mi.capture.calibrate import Calibration, calibrate
from reneus_mi.capture.exposure import measure
from reneus_mi.capture.placement import board_mesh
from reneus_mi.capture.register import Outline, register
from reneus_mi.data.undistort import output_size, pinhole_K, undistort
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError

#: Corners this many pixels of the photograph outside the container's projection still count
#: as seen through it (refraction at its edges, the corner finder's window).
EXCLUSION_MARGIN_PX = 3.0


def detect_all(board: Board, files: list[str]) -> tuple[dict, tuple[int, int]]:
    """The board's corners in every photograph, by name; the photographs' common size.

    Refuses (one line) a capture where no photograph shows a marker of the board's
    dictionary, or whose markers do not fit the stated layout; a photograph without corners
    is left out with a warning.
    """
    detections, size = {}, None
    for path in files:
        gray = photos.read_gray(path)
        here = (gray.shape[1], gray.shape[0])
        if size is None:
            size, first = here, path
        elif here != size:
            raise ReneusError(f'{path}: photograph is {here[0]}x{here[1]}, but {os.path.basename(first)} '
                              f'is {size[0]}x{size[1]}; expected one camera at one size')
        detections[os.path.basename(path)] = board.detect(gray)
    check_board(board, detections, files)
    for name, det in list(detections.items()):
        if len(det.ids) == 0:
            warnings.warn(f'{name}: left out: no board corners found (is the board in the picture, '
                          'sharp and not too oblique?)')
            del detections[name]
    return detections, size


def check_board(board: Board, detections: dict, files: list[str]) -> None:
    """One-line refusals for a board that the photographs do not show as stated."""
    folder = os.path.dirname(files[0])
    if not any(len(d.marker_ids) for d in detections.values()):
        other = board_mod.other_dictionary(photos.read_gray(files[0]), board)
        hint = (f'; {os.path.basename(files[0])} shows markers of {other} (check --dictionary)'
                if other else ' (is the board in the pictures? check --dictionary)')
        raise ReneusError(f'{folder}: no ArUco marker of {board.dictionary} in any of the {len(files)} '
                          f'photographs{hint}')
    beyond = max(int(d.marker_ids.max()) for d in detections.values() if len(d.marker_ids))
    if beyond >= board.n_markers:
        raise ReneusError(f'{folder}: marker id {beyond} seen, but a {board.columns}x{board.rows} board has '
                          f'ids 0-{board.n_markers - 1}; expected the board as stated (check --squares)')
    fits = [board.layout_fit(d) for d in detections.values() if len(d.marker_ids) >= 4]
    if fits and np.median(fits) < board_mod.LAYOUT_INLIERS:
        raise ReneusError(f'{folder}: the markers do not lie where a {board.describe()} board puts them '
                          f'(median {np.median(fits):.0%} fit); expected the board as printed (check '
                          '--squares, and whether it was made by OpenCV before 4.6)')
    if not any(len(d.ids) for d in detections.values()):
        raise ReneusError(f'{folder}: markers found but no board corner between them in any photograph; '
                          f'expected a ChArUco board of {board.describe()} (check --squares, --marker-mm)')


def load_views(files: dict, cal: Calibration, out_size, K_out) -> tuple[np.ndarray, np.ndarray]:
    """Every calibrated photograph undistorted to the dataset's pinhole camera."""
    images, valid = [], []
    for view in cal.views:
        image, ok = undistort(photos.read_rgb(files[view.name]), cal.K, cal.dist, K_out, out_size)
        images.append(np.clip(image, 0.0, 1.0))
        valid.append(ok)
    return np.stack(images), np.stack(valid)


def seen_through(cal: Calibration, shape: str, size, pose):
    """``exclude`` for :func:`calibrate`: corners inside the container's projection (with the
    lens, in the photograph) or within :data:`EXCLUSION_MARGIN_PX` of it."""
    hull = np.asarray(board_mesh(shape, size, pose).convex_hull.vertices)
    by_name = {v.name: i for i, v in enumerate(cal.views)}

    def exclude(name, pixels):
        if name not in by_name:
            return np.zeros(len(pixels), bool)
        poly = cv2.convexHull(cal.project(by_name[name], hull).astype(np.float32))
        return np.array([cv2.pointPolygonTest(poly, (float(x), float(y)), True) > -EXCLUSION_MARGIN_PX
                         for x, y in pixels])
    return exclude


def _warn_uncovered(names, valid, K, c2w, s, pose) -> None:
    """Warn where the container's projection (the training mask) reaches pixels that the
    undistorted photograph does not cover."""
    outline = Outline(s.container, s.size_mm, K, c2w)
    for v, name in enumerate(names):
        mask = np.zeros(valid[v].shape, np.uint8)
        cv2.fillConvexPoly(mask, np.round(outline.polygon(pose, v) - 0.5).astype(np.int32), 1)
        if (mask.astype(bool) & ~valid[v]).any():
            warnings.warn(f'{name}: the container reaches beyond the photograph once undistorted; '
                          'those pixels are black in the dataset')


def run(s: settings_mod.CaptureSettings, photos_dir: str, out: str) -> dict:
    """The whole capture (see the module docstring); returns what the report holds."""
    start = time.perf_counter()
    out = guards.check_output_dir(out, inputs=[photos_dir], allow=export.OUTPUTS, what='dataset folder')
    board = Board.from_settings(s)
    files = photos.list_photos(photos_dir)
    by_name = {os.path.basename(f): f for f in files}
    detections, size = detect_all(board, files)
    width, height, scale = output_size(*size, max_size=s.max_size, downscale=s.downscale)
    photos.check_memory(len(detections), size, (width, height))
    cal = calibrate(board, detections, size)
    K_out = pinhole_K(cal.K, scale)
    images, valid = load_views(by_name, cal, (width, height), K_out)
    c2w = np.stack([v.c2w for v in cal.views])
    names = [v.name for v in cal.views]
    try:
        reg = register(images, valid, K_out, c2w, board, s.container, s.size_mm, pose=s.container_pose)
    except ReneusError as e:
        # The user must see why: the overlays, with what each photograph showed.
        reg_failed = getattr(e, 'registration', None)
        export.write_overlays(out, images, K_out, c2w, board, cal, s, measured=getattr(e, 'measured', None),
                               pose=reg_failed.pose if reg_failed else None)
        raise ReneusError(f'{e} (overlays in {os.path.join(out, "overlays")})') from None
    # Corners seen through the glass leave the calibration; the place is refined from the first.
    exclude = seen_through(cal, s.container, s.size_mm, reg.pose)
    cal = calibrate(board, {n: detections[n] for n in names}, size, exclude=exclude)
    K_out = pinhole_K(cal.K, scale)
    names = [v.name for v in cal.views]
    images, valid = load_views(by_name, cal, (width, height), K_out)
    c2w = np.stack([v.c2w for v in cal.views])
    reg = register(images, valid, K_out, c2w, board, s.container, s.size_mm, pose=s.container_pose,
                   start=reg.pose)
    light = measure(images, valid, K_out, c2w, board, reg.measured, names)
    _warn_uncovered(names, valid, K_out, c2w, s, reg.pose)
    # The overlays first: a transforms.json, written last, says that the dataset is whole.
    export.write_overlays(out, images, K_out, c2w, board, cal, s, measured=reg.measured, pose=reg.pose,
                           residuals=reg.view_residuals)
    report = export.write(out, s, board, cal, K_out, light.normalise(images), reg, light)
    report['seconds'] = time.perf_counter() - start
    return report
