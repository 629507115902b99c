"""The photographs of a capture: listing, reading, and their size in memory.

Photographs are read as the sensor recorded them (EXIF orientation ignored): the lens's
intrinsics belong to the sensor, and a shot in portrait is a camera rolled by 90 degrees,
which the calibration welcomes (it pins the principal point down).
"""
from __future__ import annotations

import os

import cv2
import numpy as np

from reneus_mi import limits
from reneus_mi.errors import ReneusError

#: File types taken as photographs.
PHOTO_EXTENSIONS = ('.jpg', '.jpeg', '.png', '.tif', '.tiff')
_FLAGS = cv2.IMREAD_IGNORE_ORIENTATION


def list_photos(folder: str) -> list[str]:
    """The photographs in ``folder``, sorted by name; an error when there are none."""
    if not os.path.isdir(folder):
        raise ReneusError(f'{folder}: photographs folder does not exist')
    files = sorted(os.path.join(folder, f) for f in os.listdir(folder)
                   if os.path.splitext(f)[1].lower() in PHOTO_EXTENSIONS and not f.startswith('.'))
    if not files:
        raise ReneusError(f"{folder}: no photographs ({', '.join(PHOTO_EXTENSIONS)}) in the folder")
    return files


def read_gray(path: str) -> np.ndarray:
    """An 8-bit grey version of a photograph (for finding the board)."""
    image = cv2.imread(path, cv2.IMREAD_GRAYSCALE | _FLAGS)
    if image is None:
        raise ReneusError(f'{path}: unreadable photograph (expected a JPEG, PNG or TIFF file)')
    return image


def read_rgb(path: str) -> np.ndarray:
    """A photograph as (H,W,3) RGB float32 display values in [0, 1]."""
    image = cv2.imread(path, cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH | _FLAGS)
    if image is None:
        raise ReneusError(f'{path}: unreadable photograph (expected a JPEG, PNG or TIFF file)')
    scale = 65535.0 if image.dtype == np.uint16 else 255.0
    return image[..., ::-1].astype(np.float32) / scale


def image_size(path: str) -> tuple[int, int]:
    """(width, height) of a photograph as the sensor recorded it."""
    gray = read_gray(path)
    return gray.shape[1], gray.shape[0]


def check_memory(n: int, size: tuple[int, int], out_size: tuple[int, int]) -> None:
    """Refuse before reading when the dataset's images would not fit in memory.

    Held at once: every output image (float32 RGB, the undistorted and the normalised copy)
    and one photograph being converted (8-bit, float32 and its reduced copy).
    """
    width, height = size
    w, h = out_size
    need = n * w * h * 3 * 4 * 2 + width * height * (3 + 12 + 12) + w * h * 16
    limits.check_memory(need, f'{n} photographs of {width}x{height} scaled to {w}x{h} '
                              '(lower it with --max-size N or --downscale F)')
