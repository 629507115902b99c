"""From a folder of photographs to a dataset: :func:`run`, the pipeline of ``python -m
reneus_mi.capture PHOTOS -o DATASET`` (:mod:`reneus_mi.capture.__main__`) and of a batch's
capture folders.

1. Read every photograph once, in parallel, whole or refused by name
   (:mod:`~reneus_mi.capture.photos`): find the board in it (:mod:`~reneus_mi.capture.charuco`)
   and keep a copy reduced to the working size (the dataset's, at most
   :data:`~reneus_mi.capture.crops.WORK_MAX_SIZE`); refuse, in one line, a capture where no
   photograph shows the board, or shows another dictionary or layout.
2. Calibrate (:mod:`~reneus_mi.capture.calibrate`), leaving out photographs that cannot take part.
3. Undistort every reduced copy to the working pinhole camera: the dataset's, scaled by
   ``--max-size`` or ``--downscale``, at the working size (:mod:`~reneus_mi.data.undistort`;
   memory checked before reading).
4. Find the container (:mod:`~reneus_mi.capture.register`), or take ``--container-pose``.
5. Calibrate again without the corners seen through the container, undistort again to the
   dataset's camera (:func:`dataset_frame`), refine the container's place from the first one:
   each pass is :func:`locate`.
6. Measure each photograph's exposure, C_out and the print's brightness
   (:mod:`~reneus_mi.capture.exposure`) and normalise the exposures.
7. Write an overlay per photograph, then the dataset (:mod:`~reneus_mi.capture.writer`;
   its ``transforms.json`` last: a folder that has one holds the whole dataset): of each view
   the window around the container, undistorted at the dataset's scale from the photograph
   (:mod:`~reneus_mi.capture.crops`: decoded again where the working copy is smaller).
"""
from __future__ import annotations

import dataclasses
import os
import time
import warnings
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
from tqdm import tqdm

from reneus_mi.capture import charuco
from reneus_mi.capture import photos, settings as settings_mod, writer
from reneus_mi.capture.charuco import Board
from reneus_mi.capture.crops import WORK_MAX_SIZE, CroppedViews, container_windows
from reneus_mi.capture.calibrate import (EXTRAPOLATION_WARN_PX, Calibration, Coverage, calibrate, coverage,
                                        crop_to_coverage)
from reneus_mi.capture.exposure import Light, measure
from reneus_mi.capture.placement import board_mesh
from reneus_mi.capture.register import Outline, Registration, register
from reneus_mi.data.images import reduction, scaled_size
from reneus_mi.data.undistort import output_size, pinhole_K, undistort
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError

#: Corners this many pixels of the photograph outside the container's projection still count
#: as seen through it (refraction at its edges, the corner finder's window).
EXCLUSION_MARGIN_PX = 3.0


#: Fewest views a dataset is made of: a reconstruction needs the container seen all around
#: (the paper used 60; docs/capture.md asks for 40-80), and a lens calibrated from a handful
#: of photographs is extrapolated over most of the frame.
MIN_DATASET_VIEWS = 8
#: Why a photograph without the board's corners is left out.
NO_CORNERS = 'no board corners found (is the board in the picture, sharp and not too oblique?)'


def read_all(board: Board, shots: list[photos.Photo], kept: tuple[int, int]) -> tuple[dict, dict]:
    """Every photograph decoded once, in parallel: the board's corners found in it (by name)
    and the copy of it reduced to ``kept`` (width, height) that the dataset is made from.

    Refuses (one line) a capture where no photograph shows a marker of the board's
    dictionary, or whose markers do not fit the stated layout; a photograph without corners
    is left out with a warning.
    """
    def one(photo):
        rgb = photos.decode(photo)
        return board.detect(photos.grey(rgb)), photos.reduce(rgb, kept)
    with ThreadPoolExecutor(photos.WORKERS) as pool:
        results = list(tqdm(pool.map(one, shots), total=len(shots), desc='read, find the board', unit='photo',
                            disable=None, leave=False))
    detections = {p.name: det for p, (det, _) in zip(shots, results)}
    reduced = {p.name: image for p, (_, image) in zip(shots, results)}
    check_board(board, detections, shots, reduced)
    for name, det in list(detections.items()):
        if len(det.ids) == 0:
            warnings.warn(f'{name}: left out: {NO_CORNERS}')
            del detections[name]
    return detections, reduced


def check_board(board: Board, detections: dict, shots: list[photos.Photo], reduced: dict) -> None:
    """One-line refusals for a board that the photographs do not show as stated."""
    folder = os.path.dirname(shots[0].path)
    if not any(len(d.marker_ids) for d in detections.values()):
        first = shots[0].name
        other = charuco.other_dictionary(photos.grey(reduced[first]), board)
        hint = (f'; {first} shows markers of {other} (check --dictionary)'
                if other else ' (is the board in the pictures? check --dictionary)')
        raise ReneusError(f'{folder}: no ArUco marker of {board.dictionary} in any of the {len(shots)} '
                          f'photographs{hint}')
    beyond = max(int(d.marker_ids.max()) for d in detections.values() if len(d.marker_ids))
    if beyond >= board.n_markers:
        raise ReneusError(f'{folder}: marker id {beyond} seen, but a {board.columns}x{board.rows} board has '
                          f'ids 0-{board.n_markers - 1}; expected the board as stated (check --squares)')
    fits = [board.layout_fit(d) for d in detections.values() if len(d.marker_ids) >= 4]
    if fits and np.median(fits) < charuco.LAYOUT_INLIERS:
        raise ReneusError(f'{folder}: the markers do not lie where a {board.describe()} board puts them '
                          f'(median {np.median(fits):.0%} fit); expected the board as printed (check '
                          '--squares, and whether it was made by OpenCV before 4.6)')
    if not any(len(d.ids) for d in detections.values()):
        raise ReneusError(f'{folder}: markers found but no board corner between them in any photograph; '
                          f'expected a ChArUco board of {board.describe()} (check --squares, --marker-mm)')


def load_views(reduced: dict, cal: Calibration, out_size, K_out) -> tuple[np.ndarray, np.ndarray]:
    """Every calibrated photograph undistorted to the dataset's pinhole camera, from its
    reduced copy (the intrinsics follow the reduction exactly)."""
    images, valid = [], []
    for view in tqdm(cal.views, desc='undistort', unit='photo', disable=None, leave=False):
        copy = reduced[view.name]
        K = np.diag([copy.shape[1] / cal.width, copy.shape[0] / cal.height, 1.0]) @ cal.K
        image, ok = undistort(copy, K, cal.dist, K_out, out_size)
        images.append(image.astype(np.float32) / 255.0)
        valid.append(ok)
    return np.stack(images), np.stack(valid)


def container_hull(settings: settings_mod.CaptureSettings, pose) -> np.ndarray:
    """The corners of the container's convex hull on the board at ``pose`` (mm)."""
    return np.asarray(board_mesh(settings.container, settings.size_mm, pose,
                                 edge=settings.edge_mm).convex_hull.vertices)


def seen_through(cal: Calibration, settings: settings_mod.CaptureSettings, pose):
    """``exclude`` for :func:`calibrate`: corners inside the container's projection (with the
    lens, in the photograph) or within :data:`EXCLUSION_MARGIN_PX` of it."""
    hull = container_hull(settings, pose)
    by_name = {v.name: i for i, v in enumerate(cal.views)}

    def exclude(name, pixels):
        if name not in by_name:
            return np.zeros(len(pixels), bool)
        poly = cv2.convexHull(cal.project(by_name[name], hull).astype(np.float32))
        return np.array([cv2.pointPolygonTest(poly, (float(x), float(y)), True) > -EXCLUSION_MARGIN_PX
                         for x, y in pixels])
    return exclude


def _warn_uncovered(names, valid, K, c2w, settings, pose) -> None:
    """Warn where the container's projection (the training mask) reaches pixels that the
    undistorted photograph does not cover."""
    outline = Outline(settings.container, settings.size_mm, K, c2w, settings.edge_mm)
    for v, name in enumerate(names):
        mask = np.zeros(valid[v].shape, np.uint8)
        cv2.fillConvexPoly(mask, np.round(outline.polygon(pose, v) - 0.5).astype(np.int32), 1)
        if (mask.astype(bool) & ~valid[v]).any():
            warnings.warn(f'{name}: the container reaches beyond the photograph once undistorted; '
                          'those pixels are black in the dataset')


def run(settings: settings_mod.CaptureSettings, photos_dir: str, out: str, *, crop: bool = False) -> dict:
    """The whole capture (see the module docstring); returns what the report holds. ``settings``: the
    settings as stated (a size measured from the photographs replaces the stated one in the
    dataset). ``crop``: the dataset's images cropped to the part of the frame the board covered."""
    start = time.perf_counter()
    out = guards.check_output_dir(out, inputs=[photos_dir], allow=writer.OUTPUTS, what='dataset folder')
    board = Board.from_settings(settings)
    shots = photos.orientations(photos.list_photos(photos_dir))
    size = shots[0].size
    width, height, scale = output_size(*size, max_size=settings.max_size, downscale=settings.downscale)
    work = reduction(width, height, WORK_MAX_SIZE)
    kept = scaled_size(width, height, work)
    photos.check_memory(len(shots), size, kept, kept=kept, workers=photos.WORKERS)
    # The longest stage, and the progress bars show only on a terminal: say what it does.
    print(f'reading {len(shots)} photographs of {size[0]}x{size[1]} ({size[0] * size[1] / 1e6:.0f} MP) and '
          f'finding the board in them, {photos.WORKERS} at a time', flush=True)
    detections, reduced = read_all(board, shots, kept)
    left_out = {p.name: NO_CORNERS for p in shots if p.name not in detections}
    cal = calibrate(board, detections, size)
    left_out.update(cal.dropped)
    # The first pass only places the container: its views are undistorted by the first calibration.
    first = locate(board, reduced, cal, kept, pinhole_K(cal.K, scale * work), settings, out).reg
    cal = recalibrate(board, detections, size, cal, measured(settings, first), first.pose, left_out, photos_dir)
    frame = dataset_frame(board, cal, pinhole_K(cal.K, scale), (width, height), work, crop)
    second = locate(board, reduced, cal, frame.kept, np.diag([work, work, 1.0]) @ frame.K, settings, out,
                    start=first.pose)
    found = measured(settings, second.reg)
    light = check_and_overlay(out, board, cal, found, second)
    reg, c2w = second.reg, second.c2w
    del second   # the working copies' views: the crops are decoded from the photographs
    hull = container_hull(found, reg.pose)
    by_name = {p.name: p for p in shots}

    def lens_of(v):
        """A view's photograph: the working copy where the dataset is no finer, else decoded again."""
        name = cal.views[v].name
        rgb = reduced[name] if work == 1.0 else photos.decode(by_name[name])
        return rgb, np.diag([rgb.shape[1] / cal.width, rgb.shape[0] / cal.height, 1.0]) @ cal.K, cal.dist
    views = CroppedViews(container_windows(hull, frame.K, c2w, frame.size), frame.K, lens_of, light.factors)
    report = writer.write(out, found, board, cal, frame.K, frame.size, views, reg, light, left_out, frame.cover,
                          photos.camera_exif(shots[0].path), given=settings)
    report['seconds'] = time.perf_counter() - start
    return report


@dataclasses.dataclass
class Located:
    """A pass over the calibrated views: each undistorted at the working size (intrinsics
    ``K``), and the container found in them."""
    images: np.ndarray
    valid: np.ndarray
    K: np.ndarray
    c2w: np.ndarray
    names: list[str]
    reg: Registration


@dataclasses.dataclass
class Frame:
    """The dataset's pinhole camera (``K`` at ``size``), the working copies' size (``kept``,
    the dataset's reduced by ``work``) and the board's coverage of the frame."""
    size: tuple[int, int]
    K: np.ndarray
    kept: tuple[int, int]
    cover: Coverage


def locate(board: Board, reduced: dict, cal: Calibration, kept, K_work,
           settings: settings_mod.CaptureSettings, out: str, start=None) -> Located:
    """Undistort the calibrated views to the working camera and find the container in them
    (from ``start``, the place an earlier pass found). A failure writes the overlays, with what
    each photograph showed, and names them: the user must see why."""
    images, valid = load_views(reduced, cal, kept, K_work)
    c2w = np.stack([v.c2w for v in cal.views])
    try:
        # A solid block stated as a box, its edges not stated: polished blocks are rounded.
        rounding = settings.container == 'box' and settings.edge_mm is None and settings.wall_mm is None
        reg = register(images, valid, K_work, c2w, board, settings.container, settings.size_mm,
                       pose=settings.container_pose, start=start, edge=settings.edge_mm, rounding=rounding)
    except ReneusError as e:
        failed = getattr(e, 'registration', None)
        writer.write_overlays(out, images, K_work, c2w, board, cal, settings,
                              measured=getattr(e, 'measured', None), pose=failed.pose if failed else None)
        raise ReneusError(f'{e} (overlays in {os.path.join(out, "overlays")})') from None
    return Located(images, valid, K_work, c2w, [v.name for v in cal.views], reg)


def measured(settings: settings_mod.CaptureSettings, reg: Registration) -> settings_mod.CaptureSettings:
    """The settings with the container's size and a block's rounded edges as the photographs
    measured them, where they did."""
    if reg.size_measured:
        settings = dataclasses.replace(settings, size_mm=reg.best_size)
    if reg.edge_mm is not None:
        settings = dataclasses.replace(settings, container='rounded', edge_mm=reg.edge_mm)
    return settings


def recalibrate(board: Board, detections: dict, size, cal: Calibration,
                settings: settings_mod.CaptureSettings, pose, left_out: dict, photos_dir: str) -> Calibration:
    """``cal``'s photographs calibrated again without the corners seen through the container
    at ``pose``; those it drops join ``left_out``. Refuse a capture left with too few."""
    again = calibrate(board, {v.name: detections[v.name] for v in cal.views}, size,
                      exclude=seen_through(cal, settings, pose))
    left_out.update({n: f'{r} (once the corners seen through the container were left out)'
                     for n, r in again.dropped.items()})
    if len(again.views) < MIN_DATASET_VIEWS:
        why = '; '.join(f'{n}: {r}' for n, r in list(left_out.items())[:2])
        raise ReneusError(f'{os.path.abspath(photos_dir)}: {len(again.views)} photographs can be used '
                          f'({len(left_out)} left out{": " + why if why else ""}); expected at least '
                          f'{MIN_DATASET_VIEWS}: the container seen all around, 40-80 photographs in three '
                          'rings (docs/capture.md)')
    return again


def dataset_frame(board: Board, cal: Calibration, K_out: np.ndarray, size, work: float, crop: bool) -> Frame:
    """The dataset's camera: the whole frame (warned where the board left the lens model
    extrapolated), or with ``crop`` the part of it the board covered."""
    cover = coverage(board, cal)
    if crop:
        size, K_out, box = crop_to_coverage(cal, cover, K_out, size)
        cover = dataclasses.replace(cover, crop=box)
    elif cover.extrapolated_px > EXTRAPOLATION_WARN_PX:
        warnings.warn(f'the board covered {cover.share:.0%} of the frame; beyond it the lens model is '
                      f'uncertain by up to {cover.extrapolated_px:.1f} px (at x={cover.worst[0]:.0f}, '
                      f'y={cover.worst[1]:.0f}), and so are the dataset\'s pixels there: take photographs '
                      'with the board in the frame\'s corners too, or crop to what it covered (--crop-to-coverage)')
    return Frame(tuple(size), K_out, scaled_size(*size, work), cover)


def check_and_overlay(out: str, board: Board, cal: Calibration, settings: settings_mod.CaptureSettings,
                      located: Located) -> Light:
    """The photographs' exposure and light measured, pixels beyond them warned of, and an
    overlay written per photograph (before the dataset: a ``transforms.json``, written last,
    says that the dataset is whole)."""
    reg = located.reg
    light = measure(located.images, located.valid, located.K, located.c2w, board, reg.measured, located.names)
    _warn_uncovered(located.names, located.valid, located.K, located.c2w, settings, reg.pose)
    writer.write_overlays(out, located.images, located.K, located.c2w, board, cal, settings,
                          measured=reg.measured, pose=reg.pose, residuals=reg.view_residuals)
    return light
