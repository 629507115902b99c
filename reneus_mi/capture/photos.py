"""The photographs of a capture: listing, checking, reading, and their size in memory.

A photograph is read whole or refused by name: a truncated or corrupt file, a CMYK JPEG, a
HEIC or raw file among the JPEGs. Each is decoded once, as 8-bit RGB (Pillow's libjpeg-turbo:
a 24-megapixel JPEG in a fraction of a second), and kept only as the reduced copy the dataset
is made from; the board is found in it at full size on the way (:mod:`~reneus_mi.capture.pipeline`).

Photographs are used as the sensor recorded them: the lens's intrinsics belong to the sensor,
and a shot in portrait is a camera rolled by 90 degrees, which the calibration welcomes (it
pins the principal point down). The EXIF orientation tag is honoured where it makes a
photograph the size of the others (a picture stored turned, with a tag that turns it back);
which photographs were turned is said once (:func:`orientations`).
"""
from __future__ import annotations

import collections
import dataclasses
import os
import warnings

import cv2
import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from reneus_mi.utils import limits
from reneus_mi.utils.errors import ReneusError

#: File types taken as photographs.
PHOTO_EXTENSIONS = ('.jpg', '.jpeg', '.png', '.tif', '.tiff')
#: What a camera or a phone writes besides, which is not read here: refused by name, never
#: dropped (a specimen's views would go missing unseen).
OTHER_PHOTO_TYPES = {'.heic': 'HEIC', '.heif': 'HEIF', '.avif': 'AVIF', '.dng': 'DNG raw',
                     '.cr2': 'Canon raw', '.cr3': 'Canon raw', '.nef': 'Nikon raw', '.nrw': 'Nikon raw',
                     '.arw': 'Sony raw', '.orf': 'Olympus raw', '.rw2': 'Panasonic raw',
                     '.raf': 'Fujifilm raw', '.pef': 'Pentax raw', '.srw': 'Samsung raw'}
#: Pillow's modes of 16-bit grey samples.
_GREY16 = ('I;16', 'I;16B', 'I;16L')
#: EXIF orientations that swap width and height.
_SWAPPING = (5, 6, 7, 8)
#: Bytes per pixel of a photograph while one is decoded: Pillow's RGB, the array, the grey
#: copy the board is found in, the reduction's working copy.
DECODE_BYTES_PER_PIXEL = 12


@dataclasses.dataclass(frozen=True)
class Photo:
    """A photograph's file and what its header says."""
    path: str
    #: (width, height) as stored.
    stored: tuple[int, int]
    orientation: int | None
    #: Whether its EXIF orientation is applied (it makes the photograph the others' size).
    turn: bool = False

    @property
    def name(self) -> str:
        return os.path.basename(self.path)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) as used."""
        return self.stored[::-1] if self.turn else self.stored


def check_folder(folder: str) -> None:
    """Refuse, by name, a photographs folder that is missing or is a file."""
    if os.path.isfile(folder):
        raise ReneusError(f'{folder}: is a file; expected the folder that holds the photographs')
    if not os.path.isdir(folder):
        raise ReneusError(f'{folder}: photographs folder does not exist')


def list_photos(folder: str) -> list[str]:
    """The photographs in ``folder``, sorted by name; an error when there are none, or when
    the folder holds photographs of a type that is not read."""
    check_folder(folder)
    names = sorted(f for f in os.listdir(folder) if not f.startswith('.'))
    other = [f for f in names if os.path.splitext(f)[1].lower() in OTHER_PHOTO_TYPES]
    if other:
        kind = OTHER_PHOTO_TYPES[os.path.splitext(other[0])[1].lower()]
        more = f' and {len(other) - 1} more' if len(other) > 1 else ''
        raise ReneusError(f"{os.path.join(folder, other[0])}{more}: a {kind} file; expected JPEG, PNG or TIFF "
                          "photographs (export them as JPEG, or move them out of the folder)")
    files = [os.path.join(folder, f) for f in names if os.path.splitext(f)[1].lower() in PHOTO_EXTENSIONS]
    if not files:
        raise ReneusError(f"{folder}: no photographs ({', '.join(PHOTO_EXTENSIONS)}) in the folder")
    return files


def header(path: str) -> Photo:
    """A photograph's stored size and EXIF orientation, from its header alone."""
    guard, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None   # memory is checked from the sizes
    try:
        with Image.open(path) as image:
            return Photo(path, image.size, image.getexif().get(0x0112))
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError) as e:
        raise ReneusError(f'{path}: unreadable photograph ({e}); expected a JPEG, PNG or TIFF file') from None
    finally:
        Image.MAX_IMAGE_PIXELS = guard


#: EXIF tags of the camera, by the name the report gives them (0x8769: the Exif IFD).
_CAMERA_TAGS = {'make': (None, 0x010F), 'model': (None, 0x0110), 'lens': (0x8769, 0xA434),
                'focal_length_mm': (0x8769, 0x920A), 'date': (0x8769, 0x9003)}


def camera_exif(path: str) -> dict:
    """What a photograph's EXIF says of the camera that took it (make, model, lens, focal
    length, date taken; the tags it lacks left out): a collection's paradata."""
    with Image.open(path) as image:
        exif = image.getexif()
        out = {}
        for name, (ifd, tag) in _CAMERA_TAGS.items():
            value = (exif.get_ifd(ifd) if ifd else exif).get(tag)
            if value is None or value == '':
                continue
            out[name] = float(value) if name == 'focal_length_mm' else str(value).strip('\x00 ')
        return out


def orientations(files: list[str]) -> list[Photo]:
    """The photographs' headers, each turned by its EXIF orientation where that makes it the
    size most of them have; refuses, by name, one that no orientation makes that size."""
    photos = [header(f) for f in files]
    common, count = collections.Counter(p.stored for p in photos).most_common(1)[0]
    out, turned = [], []
    for p in photos:
        if p.stored != common:
            tag = f' (EXIF orientation {p.orientation})' if p.orientation not in (None, 1) else ''
            if p.orientation not in _SWAPPING or p.stored[::-1] != common:
                raise ReneusError(f'{p.path}: photograph is {p.stored[0]}x{p.stored[1]}{tag}, but {count} of the '
                                  f'{len(photos)} photographs are {common[0]}x{common[1]}; expected one camera '
                                  'at one size (no cropped or resized copies)')
            p = dataclasses.replace(p, turn=True)
            turned.append(p.name)
        out.append(p)
    if turned:
        warnings.warn(f"{len(turned)} photograph(s) stored turned, used as their EXIF orientation shows them "
                      f"({common[0]}x{common[1]}, as the others): {', '.join(turned)}")
    return out


def decode(photo: Photo) -> np.ndarray:
    """The photograph as (H,W,3) uint8 RGB, whole: a truncated or corrupt file, a CMYK one,
    samples that are not 8- or 16-bit are refused by name."""
    guard, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        with Image.open(photo.path) as image:
            if image.mode == 'CMYK':
                raise ReneusError(f'{photo.path}: a CMYK photograph (a print format); expected RGB as a camera '
                                  'writes it: export it again as sRGB')
            image.load()          # raises on a truncated or corrupt file
            if photo.turn:
                image = ImageOps.exif_transpose(image)
            if image.mode in _GREY16:
                grey = (np.asarray(image, np.uint16) >> 8).astype(np.uint8)
                return np.repeat(grey[..., None], 3, axis=2)
            if image.mode not in ('1', 'L', 'LA', 'P', 'PA', 'RGB', 'RGBA'):
                raise ReneusError(f'{photo.path}: photograph with {image.mode} samples; expected 8- or 16-bit '
                                  'grey or RGB')
            return np.asarray(image.convert('RGB'))
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError) as e:
        raise ReneusError(f'{photo.path}: damaged photograph ({e}); expected the whole file as the camera wrote '
                          'it (copy it again from the card, or move it out of the folder)') from None
    finally:
        Image.MAX_IMAGE_PIXELS = guard


def grey(rgb: np.ndarray) -> np.ndarray:
    """The 8-bit grey version of an RGB photograph (for finding the board)."""
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def reduce(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``rgb`` shrunk to ``size`` (width, height) by area averaging: the copy the dataset is
    undistorted from (:func:`reneus_mi.data.undistort.undistort` does the same first)."""
    if rgb.shape[1::-1] == tuple(size):
        return rgb
    return cv2.resize(rgb, tuple(size), interpolation=cv2.INTER_AREA)


def check_memory(n: int, size: tuple[int, int], out_size: tuple[int, int], *, kept: tuple[int, int] = (0, 0),
                 workers: int = 1) -> None:
    """Refuse before reading when the capture would not fit in memory.

    Held at once: every photograph's reduced 8-bit copy (``kept``), every output image
    (float32 RGB, the undistorted and the normalised copy) and, per worker, one photograph
    being decoded.
    """
    width, height = size
    w, h = out_size
    need = n * (kept[0] * kept[1] * 3 + w * h * 3 * 4 * 2) + workers * width * height * DECODE_BYTES_PER_PIXEL
    limits.check_memory(need, f'{n} photographs of {width}x{height} scaled to {w}x{h} '
                              '(lower it with --max-size N or --downscale F)')
