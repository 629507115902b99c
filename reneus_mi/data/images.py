"""Reading and writing images with :class:`mitsuba.Bitmap`: the package's one image reader and writer.

Photographs are kept as they were taken: gamma-encoded values in [0, 1].
8/16-bit PNG and JPEG are sRGB-encoded already; linear files (EXR) are encoded
with the sRGB curve on reading so that every image of a dataset means the same.
"""
from __future__ import annotations

import os

import mitsuba as mi
import numpy as np

from reneus_mi.errors import ReneusError
from reneus_mi.io import atomic_path

#: File extensions tried, in this order, for a NeRF ``file_path`` without one.
IMAGE_EXTENSIONS = ('.png', '.jpg', '.jpeg', '.exr', '.PNG', '.JPG', '.JPEG', '.EXR')

#: Image files :func:`write_image` writes.
WRITE_EXTENSIONS = ('.exr', '.png')

_WITH_ALPHA = ('YA', 'RGBA')


def read_image(path: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Return ``(rgb, alpha)``: (H,W,3) float32 in [0,1], and (H,W) float32 or None.

    Grey images are expanded to RGB; ``alpha`` is None when the file has none.
    """
    if not os.path.isfile(path):
        raise ReneusError(f"{path}: image file is missing")
    try:
        bmp = mi.Bitmap(path)
        has_alpha = bmp.pixel_format().name in _WITH_ALPHA
        rgba = np.array(bmp.convert(mi.Bitmap.PixelFormat.RGBA, mi.Struct.Type.Float32,
                                    srgb_gamma=True), dtype=np.float32)
    except RuntimeError as err:
        raise ReneusError(f"{path}: unreadable image ({err})") from None
    if not np.all(np.isfinite(rgba)):
        raise ReneusError(f"{path}: image has non-finite pixel values")
    # HDR files may exceed 1: the dataset promises display values.
    rgba = np.clip(rgba, 0.0, 1.0)
    return rgba[..., :3], (rgba[..., 3] if has_alpha else None)


def read_mask(path: str) -> np.ndarray:
    """Return a (H,W) bool mask: any channel above one half (alpha if present)."""
    rgb, alpha = read_image(path)
    return (alpha if alpha is not None else rgb.max(axis=-1)) > 0.5


def write_image(path: str, image: np.ndarray) -> None:
    """Write ``image`` atomically: EXR keeps every channel as float32; PNG is 8-bit, values
    clipped to [0, 1], (H,W) or one channel grey, three RGB, four RGBA."""
    image = np.asarray(image)
    if image.ndim == 2:
        image = image[..., None]
    ext = os.path.splitext(path)[1].lower()
    if ext == '.exr':
        bitmap = mi.Bitmap(image.astype(np.float32))
    elif ext == '.png':
        formats = {1: mi.Bitmap.PixelFormat.Y, 3: mi.Bitmap.PixelFormat.RGB, 4: mi.Bitmap.PixelFormat.RGBA}
        if image.shape[-1] not in formats:
            raise ReneusError(f'{path}: a PNG holds 1, 3 or 4 channels, the image has {image.shape[-1]}; '
                              'expected an .exr file to keep them all')
        u8 = np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)
        bitmap = mi.Bitmap(u8, pixel_format=formats[image.shape[-1]])
    else:
        raise ReneusError(f"{path}: expected a file ending in {' or '.join(WRITE_EXTENSIONS)}")
    with atomic_path(path) as tmp:
        bitmap.write(tmp)
