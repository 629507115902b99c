"""Intrinsics, lens distortion and every camera's pose from the board's corners.

OpenCV's ``calibrateCamera`` fits one camera to all photographs: fx = fy (square pixels, as
Mitsuba's sensor has), the principal point free, the distortion k1, k2, p1, p2, k3, and a
pose per photograph in the board's frame (millimetres). The fit is made robust by repeating
it without what it cannot explain:

- a corner whose reprojection error exceeds :data:`OUTLIER_SIGMAS` robust standard
  deviations of all corners' errors (and :data:`MIN_OUTLIER_PX`): corners seen through the
  glass are displaced by refraction, a detection can be wrong;
- a photograph with fewer than :data:`~reneus_mi.capture.board.MIN_CORNERS` corners left, or
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

from reneus_mi.capture.board import MIN_CORNERS, Board, Detection
from reneus_mi.data.undistort import opencv_K
from reneus_mi.utils.errors import ReneusError

#: A corner is an outlier beyond this many robust standard deviations (1.4826 MAD) ...
OUTLIER_SIGMAS = 3.0
#: ... and beyond this many pixels of the photograph. Oblique views' corners are found less
#: precisely (up to 1 px against the truth where the median is 0.09 px); left in with
#: 4 sigmas and a 0.5 px floor they moved the principal point of the simulated capture
#: 1.5 px and every camera's rotation 0.15 degree (0.7 px, 0.07 degree with these values).
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

    def project(self, view: int, points: np.ndarray) -> np.ndarray:
        """Pixels (reneus-mi convention) of board points (N,3) in a view, with distortion."""
        v = self.views[view]
        px, _ = cv2.projectPoints(np.asarray(points, np.float64).reshape(-1, 1, 3), v.rvec, v.tvec,
                                  opencv_K(self.K), self.dist)
        return px.reshape(-1, 2) + 0.5


def _fit(board: Board, views: list[View], size: tuple[int, int]):
    objects = [board.corners[v.ids[v.used]].astype(np.float32) for v in views]
    images = [(v.pixels[v.used] - 0.5).astype(np.float32) for v in views]
    flags = cv2.CALIB_FIX_ASPECT_RATIO
    K0 = np.eye(3)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(objects, images, size, K0, None, flags=flags,
                                                     criteria=criteria)
    K = np.array(K, np.float64)
    K[:2, 2] += 0.5
    for v, r, t in zip(views, rvecs, tvecs):
        v.rvec, v.tvec = np.asarray(r, np.float64).ravel(), np.asarray(t, np.float64).ravel()
    return K, np.asarray(dist, np.float64).ravel()[:5]


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
        K, dist = _fit(board, views, size)
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
                       rms=float(np.sqrt(np.mean(np.concatenate(squares)))))


def _collinear(board: Board, v: View) -> bool:
    points = board.corners[v.ids[v.used], :2]
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return spread[-1] < 0.25 * board.square_mm * np.sqrt(len(points))
