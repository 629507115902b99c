"""Pictures for a person to check a capture: one per photograph, drawn on the dataset's image.

- green dots: board corners found and used; red dots: found but left out (outliers, or
  seen through the container);
- blue crosses: where the calibration puts the corners (they sit on the dots when it is right);
- the board's axes from its origin: x red, y green (two squares long), z blue (into the table);
- yellow: the registered container's wireframe; cyan: the outline of what the photograph
  shows on the board that the bare board does not explain (the measured silhouette).
"""
from __future__ import annotations

import cv2
import numpy as np

from reneus_mi.capture.charuco import Board
from reneus_mi.capture.placement import pose_matrix
from reneus_mi.data.undistort import opencv_K
from reneus_mi.utils.io import atomic_path

_GREEN, _RED, _BLUE, _YELLOW, _CYAN = (0, 200, 0), (0, 0, 255), (255, 80, 0), (0, 230, 255), (255, 255, 0)


def _project(K, w2c, points) -> np.ndarray:
    cam = np.asarray(points, np.float64) @ w2c[:3, :3].T + w2c[:3, 3]
    uv = cam @ K.T
    return uv[:, :2] / uv[:, 2:]


def _pt(p, scale: int):
    return tuple(int(round(c * scale)) for c in np.asarray(p) - 0.5)


def wireframe(shape: str, local) -> list[tuple[np.ndarray, np.ndarray]]:
    """Segments (container frame) to draw: a box's 12 edges, or a smooth container's rims at
    its bottom and top and its vertical sides' extremes."""
    v = np.asarray(local.vertices)
    if shape == 'box':
        lo, hi = v.min(axis=0), v.max(axis=0)
        c = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])])
        pairs = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)]
        return [(c[a], c[b]) for a, b in pairs]
    segments = []
    for z in (v[:, 2].max(), v[:, 2].min()):
        ring = v[np.abs(v[:, 2] - z) < 1e-3 * np.ptp(v[:, 2]) + 1e-9]
        if len(ring) < 3:
            ring = v[np.argsort(np.abs(v[:, 2] - z))[:64]]
        angle = np.arctan2(ring[:, 1], ring[:, 0])
        ring = ring[np.argsort(angle)]
        segments += [(ring[i], ring[(i + 1) % len(ring)]) for i in range(len(ring))]
    return segments


def draw(image: np.ndarray, K: np.ndarray, c2w: np.ndarray, board: Board, *, ids=None, pixels=None,
         used=None, lens=None, segments=None, pose=None, measured=None, text: str = '') -> np.ndarray:
    """An 8-bit BGR overlay on ``image`` (display values, RGB) seen by the pinhole ``K``.

    ``pixels`` are the detected corners in the original photograph, ``lens`` = (K, dist) of
    that photograph (to carry them into the pinhole image); ``segments`` the container's
    wireframe in its own frame, placed at ``pose``.
    """
    scale = 4   # sub-pixel drawing: OpenCV's shift
    out = np.ascontiguousarray(np.round(np.clip(image, 0, 1)[..., ::-1] * 255).astype(np.uint8))
    w2c = np.linalg.inv(c2w)
    line = dict(lineType=cv2.LINE_AA, shift=2)
    if measured is not None and measured.any():
        contours, _ = cv2.findContours(measured.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(out, contours, -1, _CYAN, 1, cv2.LINE_AA)
    if pixels is not None and len(pixels):
        K0, dist = lens
        und = cv2.undistortPoints((pixels - 0.5).reshape(-1, 1, 2), opencv_K(K0), dist, P=opencv_K(K))
        und = und.reshape(-1, 2) + 0.5
        for p, ok in zip(und, used):
            cv2.circle(out, _pt(p, scale), 3 * scale, _GREEN if ok else _RED, 1, **line)
        for p in _project(K, w2c, board.corners[ids]):
            c = np.asarray(_pt(p, scale))
            cv2.line(out, tuple(c - 2 * scale), tuple(c + 2 * scale), _BLUE, 1, **line)
            cv2.line(out, (c[0] - 2 * scale, c[1] + 2 * scale), (c[0] + 2 * scale, c[1] - 2 * scale), _BLUE, 1, **line)
    axes = 2.0 * board.square_mm * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    if np.all((axes @ w2c[:3, :3].T + w2c[:3, 3])[:, 2] > 0):
        o, x, y, z = _project(K, w2c, axes)
        for end, colour in ((x, (0, 0, 255)), (y, (0, 200, 0)), (z, (255, 0, 0))):
            cv2.line(out, _pt(o, scale), _pt(end, scale), colour, 2, **line)
    if segments is not None and pose is not None:
        M = pose_matrix(pose)
        for a, b in segments:
            pa, pb = _project(K, w2c, (np.array([a, b]) @ M[:3, :3].T + M[:3, 3]))
            cv2.line(out, _pt(pa, scale), _pt(pb, scale), _YELLOW, 1, **line)
    if text:
        for colour, width in (((0, 0, 0), 3), ((255, 255, 255), 1)):
            cv2.putText(out, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, width, cv2.LINE_AA)
    return out


def write(path: str, overlay: np.ndarray) -> None:
    ok, data = cv2.imencode(".jpg", overlay, [cv2.IMWRITE_JPEG_QUALITY, 90])
    with atomic_path(path) as tmp, open(tmp, 'wb') as f:
        f.write(data.tobytes())

