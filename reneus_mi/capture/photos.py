"""The photographs of a capture: listing, reading, and their size in memory.

Photographs are read by the package's reader (:mod:`reneus_mi.data.images`) as the sensor
recorded them (``upright=False``: EXIF orientation ignored): the lens's intrinsics belong to
the sensor, and a shot in portrait is a camera rolled by 90 degrees, which the calibration
welcomes (it pins the principal point down).
"""
from __future__ import annotations

import os

import cv2
import numpy as np

from reneus_mi.data import images
from reneus_mi.utils import limits
from reneus_mi.utils.errors import ReneusError

#: File types taken as photographs.
PHOTO_EXTENSIONS = ('.jpg', '.jpeg', '.png', '.tif', '.tiff')


def list_photos(folder: str) -> list[str]:
    """The photographs in ``folder``, sorted by name; an error when there are none."""
    if not os.path.isdir(folder):
        raise ReneusError(f'{folder}: photographs folder does not exist')
    files = sorted(os.path.join(folder, f) for f in os.listdir(folder)
                   if os.path.splitext(f)[1].lower() in PHOTO_EXTENSIONS and not f.startswith('.'))
    if not files:
        raise ReneusError(f"{folder}: no photographs ({', '.join(PHOTO_EXTENSIONS)}) in the folder")
    return files


def read_rgb(path: str) -> np.ndarray:
    """A photograph as (H,W,3) RGB float32 display values in [0, 1]."""
    return images.read_image(path, upright=False)[0]


def read_gray(path: str) -> np.ndarray:
    """An 8-bit grey version of a photograph (for finding the board)."""
    gray = cv2.cvtColor(read_rgb(path), cv2.COLOR_RGB2GRAY)
    return np.round(gray * 255.0).astype(np.uint8)


def check_memory(n: int, size: tuple[int, int], out_size: tuple[int, int]) -> None:
    """Refuse before reading when the dataset's images would not fit in memory.

    Held at once: every output image (float32 RGB, the undistorted and the normalised copy)
    and one photograph being decoded (as the dataset loader decodes it) and reduced.
    """
    width, height = size
    w, h = out_size
    need = n * w * h * 3 * 4 * 2 + width * height * (images.DECODE_BYTES_PER_PIXEL + 12) + w * h * 16
    limits.check_memory(need, f'{n} photographs of {width}x{height} scaled to {w}x{h} '
                              '(lower it with --max-size N or --downscale F)')
