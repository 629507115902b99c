"""Reading and writing images: the package's one image reader and writer.

Photographs are kept as they were taken: gamma-encoded values in [0, 1].
8/16-bit PNG, JPEG and TIFF are sRGB-encoded already; linear files (EXR) are encoded
with the sRGB curve on reading so that every image of a dataset means the same.
Mitsuba's :class:`~mitsuba.Bitmap` reads PNG, JPEG and EXR; OpenCV reads TIFF
(which Mitsuba does not). :func:`image_size` reads a file's header alone, so that
a dataset's memory is known before any photograph is decoded
(:func:`check_images_fit`). A photograph whose EXIF orientation tag asks for it
to be shown turned is refused by name: the cameras were posed on one of two
pictures, and the file does not say which. The capture, which poses the cameras
itself, reads its photographs with :mod:`reneus_mi.capture.photos`.
"""
from __future__ import annotations

import os

import cv2
import mitsuba as mi
import numpy as np
import OpenEXR
from PIL import Image, UnidentifiedImageError

from reneus_mi.utils import limits
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_mitsuba_write

#: File extensions tried, in this order, for a NeRF ``file_path`` without one.
IMAGE_EXTENSIONS = ('.png', '.jpg', '.jpeg', '.exr', '.tif', '.tiff',
                    '.PNG', '.JPG', '.JPEG', '.EXR', '.TIF', '.TIFF')

#: What :func:`read_image` reads, in words.
READ_TYPES = 'a PNG, JPEG, EXR, or 8- or 16-bit TIFF file'
#: Image files :func:`write_image` writes.
WRITE_EXTENSIONS = ('.exr', '.png')

#: Bytes per pixel of a dataset while it loads: its RGB images as held (:func:`stored`,
#: 16-bit at most) and again stacked (2 x 6), its masks, the container's projection. With
#: :data:`DECODE_BYTES_PER_PIXEL` (the one photograph being decoded: its samples, the RGBA
#: float32 conversion and its copies, at its own size) an upper bound of the measured peak
#: (docs/constants.md).
LOAD_BYTES_PER_PIXEL = 32
DECODE_BYTES_PER_PIXEL = 56
#: The option that reduces the photographs as they load (optimize, scene).
REDUCE_OPTION = '--max-image-size N'

_WITH_ALPHA = ('YA', 'RGBA')
_TIFF = ('.tif', '.tiff')
#: What an EXIF orientation other than 1 asks a viewer to do with the stored pixels.
_ORIENTATIONS = {2: 'mirror it left to right', 3: 'turn it by 180 degrees', 4: 'mirror it top to bottom',
                 5: 'mirror it across its diagonal', 6: 'turn it 90 degrees clockwise',
                 7: 'mirror it across its anti-diagonal', 8: 'turn it 90 degrees counter-clockwise'}


def image_size(path: str) -> tuple[int, int]:
    """(width, height) of an image file as stored, from its header alone.

    Refuses a missing or unreadable file and an EXIF orientation other than 1 (upright), by
    name.
    """
    if not os.path.isfile(path):
        raise ReneusError(f"{path}: image file is missing")
    if os.path.splitext(path)[1].lower() == '.exr':
        try:
            lo, hi = OpenEXR.File(path, header_only=True).header()['dataWindow']
        except Exception as e:  # the binding raises several kinds for unreadable files
            raise ReneusError(f"{path}: unreadable image ({e}); expected {READ_TYPES}") from None
        return int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)
    # Pillow's guard against decompression bombs refuses large photographs outright; only the
    # header is read here, and memory is checked from it (check_images_fit).
    guard, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        with Image.open(path) as image:
            size, orientation = image.size, _orientation(image)
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError) as e:
        raise ReneusError(f"{path}: unreadable image ({e}); expected {READ_TYPES}") from None
    finally:
        Image.MAX_IMAGE_PIXELS = guard
    if orientation not in (None, 1):
        turn = _ORIENTATIONS.get(orientation, 'turn it')
        raise ReneusError(
            f"{path}: EXIF orientation {orientation} asks to {turn} for display; expected photographs "
            'stored upright (orientation 1), since the cameras were posed on either the stored or the '
            'turned picture and the file does not say which: store the pixels upright before posing '
            '(exiftran -ai), or, if the poses were computed on the stored pixels, set the tag to 1 '
            '(exiftool -n -Orientation=1)')
    return size


def _orientation(image) -> int | None:
    """The EXIF orientation tag of an opened image, read without decoding its pixels."""
    if image.format == 'PNG':
        # Pillow reads a PNG's eXIf chunk through getexif() only by decoding the whole image;
        # a chunk before the pixels is in the header's info.
        if 'exif' not in image.info:
            return None
        exif = Image.Exif()
        exif.load(image.info['exif'])
        return exif.get(0x0112)
    return image.getexif().get(0x0112)


def reduction(width: int, height: int, max_size: int) -> float:
    """The scale that brings an image's longest side down to ``max_size`` (0: 1, as it is)."""
    return min(1.0, max_size / max(width, height)) if max_size else 1.0


def scaled_size(width: int, height: int, scale: float) -> tuple[int, int]:
    """The size of an image scaled by ``scale``, each side rounded and at least one pixel."""
    return max(1, int(round(width * scale))), max(1, int(round(height * scale)))


def reduced_size(width: int, height: int, max_size: int) -> tuple[int, int]:
    """The size of an image whose longest side is brought down to ``max_size`` (0: as it is)."""
    return scaled_size(width, height, reduction(width, height, max_size))


def resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` (H,W[,C]) at ``size`` (width, height), shrunk by area averaging."""
    if image.shape[1::-1] == tuple(size):
        return image
    return cv2.resize(image, tuple(size), interpolation=cv2.INTER_AREA)


def check_images_fit(files: list[str], max_size: int, where: str, extra_per_pixel: int = 0) -> None:
    """Refuse, before any is decoded, photographs whose dataset would not fit in memory.

    ``extra_per_pixel`` is what the caller holds besides (a training run's copy on the
    device); the figures are the photographs' as reduced by ``max_size``.
    """
    sizes = [image_size(f) for f in files]
    reduced = [reduced_size(w, h, max_size) for w, h in sizes]
    pixels = sum(w * h for w, h in reduced)
    need = (pixels * (LOAD_BYTES_PER_PIXEL + extra_per_pixel)
            + max(w * h for w, h in sizes) * DECODE_BYTES_PER_PIXEL)
    (w, h), (rw, rh) = sizes[0], reduced[0]
    at = f' used at {rw}x{rh}' if (rw, rh) != (w, h) else ''
    limits.check_memory(need, f'{where}: {len(files)} photographs of {w}x{h}{at} (lower it with {REDUCE_OPTION})')


def read_image(path: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Return ``(rgb, alpha)``: (H,W,3) float32 in [0,1], and (H,W) float32 or None.

    Grey images are expanded to RGB; ``alpha`` is None when the file has none. The pixels
    as stored; refused as :func:`image_size` says.
    """
    image_size(path)
    if os.path.splitext(path)[1].lower() in _TIFF:
        rgba, has_alpha = _read_tiff(path)
    else:
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
    np.clip(rgba, 0.0, 1.0, out=rgba)
    # Copies: the RGBA array is not kept alive by views of it.
    return rgba[..., :3].copy(), (rgba[..., 3].copy() if has_alpha else None)


def _read_tiff(path: str) -> tuple[np.ndarray, bool]:
    """An 8- or 16-bit TIFF as (H,W,4) RGBA float32 display values, and whether it had alpha."""
    data = cv2.imread(path, cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    if data is None or data.dtype not in (np.uint8, np.uint16):
        kind = 'unreadable' if data is None else f'{data.dtype} samples'
        raise ReneusError(f"{path}: TIFF with {kind}; expected 8- or 16-bit integer samples (grey, "
                          'RGB or RGBA)')
    data = data.reshape(data.shape[0], data.shape[1], -1)
    channels = data.shape[2]
    if channels not in (1, 2, 3, 4):
        raise ReneusError(f"{path}: TIFF with {channels} channels; expected grey, RGB or RGBA")
    scale = np.float32(255.0 if data.dtype == np.uint8 else 65535.0)
    rgba = np.ones(data.shape[:2] + (4,), np.float32)
    colour = data[..., :1] if channels <= 2 else data[..., 2::-1]     # OpenCV reads BGR
    rgba[..., :3] = colour / scale
    if channels in (2, 4):
        rgba[..., 3] = data[..., -1] / scale
    return rgba, channels in (2, 4)


def stored(rgb: np.ndarray, eight_bit: bool) -> np.ndarray:
    """Display values in [0, 1] as a dataset holds them: 8-bit integers where the photograph had
    8 bits (``eight_bit``: :func:`holds_8_bits` of it as read), 16-bit ones otherwise, a quarter
    and a half of float32's bytes."""
    top = 255.0 if eight_bit else 65535.0
    return np.round(np.clip(rgb, 0.0, 1.0) * np.float32(top)).astype(np.uint8 if eight_bit else np.uint16)


def holds_8_bits(rgb: np.ndarray) -> bool:
    """Whether every value of an image as read is k/255: an 8-bit file, which 8 bits keep exactly."""
    scaled = np.asarray(rgb, np.float32) * np.float32(255.0)
    return bool(np.all(np.abs(scaled - np.round(scaled)) < 1e-3))


def as_float(image: np.ndarray) -> np.ndarray:
    """An image as :func:`stored` holds it (or float already) as float32 in [0, 1]."""
    if image.dtype == np.uint8:
        return image.astype(np.float32) / np.float32(255.0)
    if image.dtype == np.uint16:
        return image.astype(np.float32) / np.float32(65535.0)
    return np.asarray(image, np.float32)


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
    file_format = mi.Bitmap.FileFormat.OpenEXR if ext == '.exr' else mi.Bitmap.FileFormat.PNG
    atomic_mitsuba_write(path, lambda stream: bitmap.write(stream, file_format))
