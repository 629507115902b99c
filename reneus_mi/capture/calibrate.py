"""Intrinsics, lens distortion and every camera's pose from the board's corners.

OpenCV's ``calibrateCamera`` fits one camera to all photographs: fx = fy (square pixels, as
Mitsuba's sensor has), the principal point free, the distortion k1, k2, p1, p2, k3, and a
pose per photograph in the board's frame (millimetres). The fit is made robust by repeating
it without what it cannot explain:

- a corner whose reprojection error exceeds :data:`OUTLIER_SIGMAS` robust standard
  deviations of all corners' errors (and :data:`MIN_OUTLIER_PX`): corners seen through the
  glass are displaced by refraction, a detection can be wrong;
- a photograph with fewer than :data:`~reneus_mi.capture.charuco.MIN_CORNERS` corners left, or
  whose RMS error exceeds :data:`VIEW_RMS_FACTOR` times the median photograph's: left out of
  the dataset with a warning naming it and why.

Once the container is registered, :func:`calibrate` runs again with the corners inside its
projection (``exclude``) removed: those are seen through the glass.
"""
from __future__ import annotations

import dataclasses
import warnings

import cv2
import numpy as np

from reneus_mi.capture.charuco import MIN_CORNERS, Board, Detection
from reneus_mi.data.undistort import opencv_K
from reneus_mi.utils.errors import ReneusError

#: A corner is an outlier beyond this many robust standard deviations (1.4826 MAD) ...
OUTLIER_SIGMAS = 3.0
#: ... and beyond this many pixels of the photograph: oblique views' corners are found less
#: precisely, and left in they move the principal point (docs/constants.md).
MIN_OUTLIER_PX = 0.1
#: A photograph is left out when its RMS error exceeds this many times the median one's ...
VIEW_RMS_FACTOR = 3.0
#: ... and this many pixels.
MIN_VIEW_RMS_PX = 1.0
#: Rounds of fitting and dropping.
MAX_ROUNDS = 6
#: Fewest photographs a calibration is made from.
MIN_VIEWS = 3


@dataclasses.dataclass
class View:
    """One photograph in the calibration."""
    name: str
    #: (M,) corner ids and (M,2) pixels (reneus-mi convention) of what was detected.
    ids: np.ndarray
    pixels: np.ndarray
    #: (M,) which corners the final fit used.
    used: np.ndarray
    #: Board-to-camera rotation vector and translation (mm).
    rvec: np.ndarray = None
    tvec: np.ndarray = None
    #: RMS reprojection error (pixels) of the used corners.
    rms: float = float('nan')
    #: Standard deviations of the pose from the solve's Jacobian: rotation (degrees, the
    #: rotation vector's) and translation (mm, the camera frame's).
    rotation_std_deg: float = float('nan')
    translation_std_mm: float = float('nan')

    @property
    def c2w(self) -> np.ndarray:
        """Camera-to-board, OpenCV axes, millimetres."""
        R, _ = cv2.Rodrigues(self.rvec)
        M = np.eye(4)
        M[:3, :3] = R.T
        M[:3, 3] = -R.T @ self.tvec.ravel()
        return M


@dataclasses.dataclass
class Calibration:
    """The camera of a capture: intrinsics in reneus-mi's pixel convention, distortion, views."""
    K: np.ndarray
    dist: np.ndarray
    width: int
    height: int
    views: list[View]
    #: Photographs left out, with the reason.
    dropped: dict[str, str]
    #: RMS reprojection error of all used corners (pixels).
    rms: float
    #: Standard deviations of f, cx, cy (pixels) from the solve's Jacobian.
    K_std: np.ndarray = None

    def project(self, view: int, points: np.ndarray) -> np.ndarray:
        """Pixels (reneus-mi convention) of board points (N,3) in a view, with distortion."""
        v = self.views[view]
        px, _ = cv2.projectPoints(np.asarray(points, np.float64).reshape(-1, 1, 3), v.rvec, v.tvec,
                                  opencv_K(self.K), self.dist)
        return px.reshape(-1, 2) + 0.5


def _solve(board: Board, views: list[View], size: tuple[int, int], flags: int = 0):
    """OpenCV's solve on the views' used corners: (K in reneus-mi's convention, dist, rvecs,
    tvecs, standard deviations of the intrinsics and of the poses)."""
    objects = [board.corners[v.ids[v.used]].astype(np.float32) for v in views]
    images = [(v.pixels[v.used] - 0.5).astype(np.float32) for v in views]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    _, K, dist, rvecs, tvecs, std_in, std_ex, _ = cv2.calibrateCameraExtended(
        objects, images, size, np.eye(3), None, flags=cv2.CALIB_FIX_ASPECT_RATIO | flags, criteria=criteria)
    K = np.array(K, np.float64)
    K[:2, 2] += 0.5
    return (K, np.asarray(dist, np.float64).ravel()[:5], rvecs, tvecs, np.asarray(std_in, np.float64).ravel(),
            np.asarray(std_ex, np.float64).reshape(-1, 6))


def _fit(board: Board, views: list[View], size: tuple[int, int]):
    """Fit the camera and every view's pose (set on the views); (K, dist, std of f, cx, cy)."""
    K, dist, rvecs, tvecs, std_in, std_ex = _solve(board, views, size)
    for v, r, t, e in zip(views, rvecs, tvecs, std_ex):
        v.rvec, v.tvec = np.asarray(r, np.float64).ravel(), np.asarray(t, np.float64).ravel()
        v.rotation_std_deg = float(np.degrees(np.linalg.norm(e[:3])))
        v.translation_std_mm = float(np.linalg.norm(e[3:]))
    # OpenCV's order: fx, fy, cx, cy, k1, ...; with the aspect fixed fx follows fy, whose
    # deviation is f's (fx's is 0).
    return K, dist, std_in[[1, 2, 3]]


def _errors(board: Board, v: View, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    px, _ = cv2.projectPoints(board.corners[v.ids], v.rvec, v.tvec, opencv_K(K), dist)
    return np.linalg.norm(px.reshape(-1, 2) + 0.5 - v.pixels, axis=1)


def calibrate(board: Board, detections: dict[str, Detection], size: tuple[int, int], *,
              exclude=None) -> Calibration:
    """Calibrate from the photographs' detections (by name); ``size`` is (width, height).

    ``exclude(name, pixels) -> bool array`` marks corners not to use (seen through the
    container). Photographs that cannot take part are dropped with a warning.
    """
    dropped: dict[str, str] = {}
    views = []
    for name, det in detections.items():
        used = np.ones(len(det.ids), bool)
        if exclude is not None and len(det.ids):
            used &= ~exclude(name, det.pixels)
        views.append(View(name, det.ids, det.pixels, used))

    def drop(view: View, reason: str) -> None:
        dropped[view.name] = reason
        warnings.warn(f'{view.name}: left out: {reason}', stacklevel=3)

    for round_ in range(MAX_ROUNDS + 1):
        kept = []
        for v in views:
            n = int(v.used.sum())
            if n < MIN_CORNERS:
                drop(v, f'{n} board corners usable (of {len(v.ids)} found); expected at least {MIN_CORNERS}')
            elif _collinear(board, v):
                drop(v, 'the usable board corners lie on one line; expected corners of several rows and columns')
            else:
                kept.append(v)
        views = kept
        if len(views) < MIN_VIEWS:
            raise ReneusError(f'{len(views)} photographs with enough board corners; expected at least '
                              f'{MIN_VIEWS} ({"; ".join(f"{k}: {r}" for k, r in list(dropped.items())[:3])})')
        K, dist, K_std = _fit(board, views, size)
        if round_ == MAX_ROUNDS:
            break
        errors = [_errors(board, v, K, dist) for v in views]
        used_errors = np.concatenate([e[v.used] for e, v in zip(errors, views)])
        sigma = 1.4826 * np.median(np.abs(used_errors - np.median(used_errors)))
        limit = max(np.median(used_errors) + OUTLIER_SIGMAS * sigma, MIN_OUTLIER_PX)
        changed = False
        for v, e in zip(views, errors):
            outliers = v.used & (e > limit)
            if outliers.any():
                v.used &= ~outliers
                changed = True
        rms = np.array([np.sqrt(np.mean(e[v.used] ** 2)) for e, v in zip(errors, views)])
        bad = rms > max(VIEW_RMS_FACTOR * np.median(rms), MIN_VIEW_RMS_PX)
        if bad.any():
            for v, r in zip(np.asarray(views, object)[bad], rms[bad]):
                drop(v, f'RMS reprojection error {r:.2f} px; expected at most '
                        f'{max(VIEW_RMS_FACTOR * np.median(rms), MIN_VIEW_RMS_PX):.2f} px '
                        f'({VIEW_RMS_FACTOR:g}x the median photograph\'s)')
            views = [v for v, b in zip(views, bad) if not b]
            changed = True
        if not changed:
            break
    squares = []
    for v in views:
        e = _errors(board, v, K, dist)[v.used]
        v.rms = float(np.sqrt(np.mean(e ** 2)))
        squares.append(e ** 2)
    return Calibration(K=K, dist=dist, width=size[0], height=size[1], views=views, dropped=dropped,
                       rms=float(np.sqrt(np.mean(np.concatenate(squares)))), K_std=K_std)


def _collinear(board: Board, v: View) -> bool:
    points = board.corners[v.ids[v.used], :2]
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return spread[-1] < 0.25 * board.square_mm * np.sqrt(len(points))


@dataclasses.dataclass
class Coverage:
    """Where the board's used corners lay in the frame, over all photographs, and how far
    the lens model is extrapolated beyond."""
    #: Share of the frame inside the convex hull of every used corner.
    share: float
    #: The hull (M,2), pixels (reneus-mi convention).
    hull: np.ndarray
    #: Largest disagreement beyond the hull, growing from its edge, between the lens model and
    #: one without k3 fitted to the same corners (pixels): what the model asserts where the
    #: board never was, which the corners cannot tell.
    extrapolated_px: float
    #: Where that is (pixels).
    worst: tuple[float, float]
    #: The dataset's images cropped to the covered area (--crop-to-coverage): x, y, width,
    #: height of the crop in the uncropped dataset image, pixels; None: not cropped.
    crop: tuple[int, int, int, int] | None = None


#: Frame points sampled per side for :func:`coverage`.
COVERAGE_GRID = 48
#: Above this many pixels of extrapolation the command warns.
EXTRAPOLATION_WARN_PX = 1.0


def coverage(board: Board, cal: Calibration) -> Coverage:
    """The frame's coverage by the board over all photographs (:class:`Coverage`).

    Two lens models that explain the corners alike (the fitted one, and one refitted with k3
    held at 0) may part beyond them: the largest growth of their disagreement from the hull's
    edge to a pixel outside it says how far the dataset's pixels there can be trusted.
    """
    corners = np.concatenate([v.pixels[v.used] for v in cal.views])
    hull = cv2.convexHull(corners.astype(np.float32)).reshape(-1, 2).astype(np.float64)
    share = cv2.contourArea(hull.astype(np.float32)) / (cal.width * cal.height)
    xs = np.linspace(0.5, cal.width - 0.5, COVERAGE_GRID)
    ys = np.linspace(0.5, cal.height - 0.5, COVERAGE_GRID)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    outside = np.array([cv2.pointPolygonTest(hull.astype(np.float32), (float(x), float(y)), False) < 0
                        for x, y in grid])
    if not outside.any():
        return Coverage(float(share), hull, 0.0, (float('nan'), float('nan')))
    K2, dist2, *_ = _solve(board, cal.views, (cal.width, cal.height), cv2.CALIB_FIX_K3)
    points = grid[outside]
    nearest = _nearest_on_polygon(points, hull)

    def disagreement(pixels):
        return cal.K[0, 0] * (_rays(cal.K, cal.dist, pixels) - _rays(K2, dist2, pixels))
    change = np.linalg.norm(disagreement(points) - disagreement(nearest), axis=1)
    k = int(np.argmax(change))
    return Coverage(float(share), hull, float(change[k]), tuple(float(c) for c in points[k]))


def _rays(K: np.ndarray, dist: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(N,2) normalised pinhole coordinates of photograph pixels through a lens."""
    return cv2.undistortPoints((pixels - 0.5).reshape(-1, 1, 2), opencv_K(K), dist).reshape(-1, 2)


def _nearest_on_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """The nearest point of a closed polygon's edges to each point."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum('pek,ek->pe', points[:, None] - a[None], ab) / np.maximum((ab ** 2).sum(1), 1e-12), 0, 1)
    candidates = a[None] + t[..., None] * ab[None]
    best = np.argmin(np.linalg.norm(candidates - points[:, None], axis=-1), axis=1)
    return candidates[np.arange(len(points)), best]


def crop_to_coverage(cal: Calibration, cover: Coverage, K_out: np.ndarray, size: tuple[int, int]):
    """The largest rectangle of the dataset image's shape, about the covered area's centre,
    every pixel of which the board's corners covered (through the lens, in the photograph):
    ``(size, K, crop)`` of the cropped pinhole camera (``crop``: x, y, width, height in the
    uncropped image)."""
    width, height = size
    hull = cover.hull.astype(np.float32)
    K_cv = opencv_K(cal.K)

    def in_photo(px):
        rays = np.c_[(px - K_out[:2, 2]) / K_out[0, 0], np.ones(len(px))]
        seen, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K_cv, cal.dist)
        return seen.reshape(-1, 2) + 0.5
    centre = cv2.undistortPoints((hull.mean(axis=0) - 0.5).reshape(1, 1, 2).astype(np.float64), K_cv, cal.dist,
                                 P=opencv_K(K_out)).reshape(2) + 0.5
    edge = np.linspace(-1.0, 1.0, 17)
    outline = np.concatenate([np.c_[edge, np.full_like(edge, s)] for s in (-1.0, 1.0)] +
                             [np.c_[np.full_like(edge, s), edge] for s in (-1.0, 1.0)])

    def fits(t):
        px = centre + outline * (0.5 * t * width, 0.5 * t * height)
        if (px < 0).any() or (px[:, 0] > width).any() or (px[:, 1] > height).any():
            return False
        return all(cv2.pointPolygonTest(hull, (float(x), float(y)), False) >= 0 for x, y in in_photo(px))
    lo, hi = 0.0, 1.0
    for _ in range(30):
        lo, hi = ((lo + hi) / 2, hi) if fits((lo + hi) / 2) else (lo, (lo + hi) / 2)
    w, h = max(1, int(lo * width)), max(1, int(lo * height))
    x0, y0 = int(np.floor(centre[0] - w / 2)), int(np.floor(centre[1] - h / 2))
    x0, y0 = min(max(x0, 0), width - w), min(max(y0, 0), height - h)
    K = np.array(K_out, np.float64)
    K[0, 2] -= x0
    K[1, 2] -= y0
    return (w, h), K, (x0, y0, w, h)
