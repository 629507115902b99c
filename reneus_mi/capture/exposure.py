"""The light of a capture and each photograph's exposure, measured from the photographs.

- **Exposure.** A photographer's exposure drifts between shots (auto-exposure, a flash that
  charges differently, a shutter of a fraction of a stop); the loss must not blame the
  field for it. The board's white print is the same paper in every view (a light tent
  lights it evenly, and paper is nearly Lambertian), so the median linear value of the
  pixels wholly on white print, away from the container, is each photograph's gain up to
  one constant. Photographs are normalised to the darkest one's exposure (so that no value
  is pushed above 1): display values times ``gain^(-1/γ)``, γ the trainer's camera response.
- **C_out** (the paper's ambient light, Sec. 4, measured "from the background"): the median
  linear value, after normalisation, of the pixels that see neither the printed board (nor
  one square around it) nor the container: the tent. When no photograph shows the tent, the
  white print's value stands in for it, with a warning.
- **The board's brightness** (white and black print, linear RGB after normalisation): what a
  model of the board under the container needs.
"""
from __future__ import annotations

import dataclasses
import warnings

import cv2
import numpy as np

from reneus_mi.capture.charuco import Board
from reneus_mi.capture.register import board_levels, linear, predict_board
from reneus_mi.render.config import RenderConfig
from reneus_mi.utils.errors import ReneusError

#: Pixels this share of the container's apparent size around its silhouette are left out of
#: every measurement (its shadow, its reflections, refraction at its edges).
AROUND_CONTAINER = 0.15


@dataclasses.dataclass
class Light:
    #: (N,) exposure of each photograph relative to the darkest (>= 1).
    gains: np.ndarray
    #: Linear RGB of the tent (C_out) and of the white and black print, at the darkest exposure.
    ambient: np.ndarray
    white: np.ndarray
    black: np.ndarray
    #: Where C_out came from: 'background' or 'board white'.
    ambient_from: str

    @property
    def factors(self) -> np.ndarray:
        """What each view's display values are multiplied by to look as if taken at the darkest
        exposure."""
        return self.gains ** (-1.0 / RenderConfig.gamma)


def _around(silhouette: np.ndarray) -> np.ndarray:
    size = np.sqrt(max(silhouette.sum(), 1))
    r = max(2, int(round(AROUND_CONTAINER * size)))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.dilate(silhouette.astype(np.uint8), disc) > 0


def measure(images: np.ndarray, valid: np.ndarray, K: np.ndarray, c2w: np.ndarray, board: Board,
            silhouettes: np.ndarray, names: list[str]) -> Light:
    """Exposure gains, C_out and the print's brightness from undistorted photographs (display
    values) whose container silhouettes are known."""
    n, h, w = images.shape[:3]
    whites, blacks, backgrounds = [], [], []
    for v in range(n):
        lin = linear(images[v])
        away = valid[v] & ~_around(silhouettes[v])
        print_share, on_board = predict_board(board, K, c2w[v], (w, h))
        black, white = board_levels(lin, print_share, on_board, away)
        if white is None:
            raise ReneusError(f'{names[v]}: too little of the printed board is seen away from the '
                              'container to measure the exposure; expected the board around it')
        whites.append(white)
        blacks.append(black)
        tent = away & ~_sees_board(K, c2w[v], (w, h), board, board.square_mm)
        if tent.sum() >= 64:
            backgrounds.append(np.median(lin[tent], axis=0))
        else:
            backgrounds.append(None)
    whites, blacks = np.array(whites), np.array(blacks)
    level = whites.mean(axis=1)
    gains = level / level.min()
    white = np.median(whites / gains[:, None], axis=0)
    black = np.median(blacks / gains[:, None], axis=0)
    tent = [b / g for b, g in zip(backgrounds, gains) if b is not None]
    if tent:
        ambient, source = np.median(np.array(tent), axis=0), 'background'
    else:
        warnings.warn('no photograph shows the background beyond the board; C_out is taken as the '
                      'white print\'s brightness (refine it with --refine-light ambient)')
        ambient, source = white, 'board white'
    return Light(gains=gains, ambient=ambient, white=white, black=black, ambient_from=source)


def _sees_board(K, c2w, size, board: Board, margin: float) -> np.ndarray:
    """Pixels whose ray meets the board's plane within ``margin`` of the printed pattern."""
    w, h = size
    ys, xs = np.mgrid[:h, :w]
    d = np.stack([xs + 0.5, ys + 0.5, np.ones_like(xs, dtype=float)], -1) @ np.linalg.inv(K).T @ c2w[:3, :3].T
    o = c2w[:3, 3]
    with np.errstate(divide='ignore', invalid='ignore'):
        t = -o[2] / d[..., 2]
    p = o[:2] + t[..., None] * d[..., :2]
    bw, bh = board.size_mm
    return (t > 0) & (p[..., 0] > -margin) & (p[..., 0] < bw + margin) & (p[..., 1] > -margin) & (p[..., 1] < bh + margin)
