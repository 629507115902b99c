"""The photographs of a capture: listing, checking, reading, and their size in memory.

A photograph is read whole, once, or refused by name: a truncated or corrupt file, a CMYK JPEG,
a HEIC or raw file among the JPEGs, two photographs whose names differ only in case or
extension (their dataset images would be one file). A JPEG is decoded strictly
(libjpeg-turbo through simplejpeg, whose recoverable errors are errors here): libjpeg, and so
Pillow, decode damaged entropy data with a warning only, and the garbage would become a
training view. A photograph copied under a second name is named and used once. Each is
decoded once, as 8-bit RGB (a 24-megapixel JPEG in a fraction of a second), and kept only as
the reduced copy the dataset is made from; the board is found in it at full size on the way
(:mod:`~reneus_mi.capture.pipeline`).

Photographs are used as the sensor recorded them: the lens's intrinsics belong to the sensor,
and a shot in portrait is a camera rolled by 90 degrees, which the calibration welcomes (it
pins the principal point down). The EXIF orientation tag is honoured where it makes a
photograph the size of the others (a picture stored turned, with a tag that turns it back);
which photographs were turned is said once (:func:`orientations`).
"""
from __future__ import annotations

import collections
import dataclasses
import hashlib
import os
import warnings

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError
import simplejpeg

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
#: EXIF orientations that swap width and height, and the turn that shows each as intended.
_SWAPPING = {5: Image.Transpose.TRANSPOSE, 6: Image.Transpose.ROTATE_270, 7: Image.Transpose.TRANSVERSE,
             8: Image.Transpose.ROTATE_90}
#: Bytes per pixel of a photograph while the capture takes it in (not the dataset loader's
#: DECODE_BYTES_PER_PIXEL): the file, the RGB array, the grey copy
#: the board is found in, the reduction's working copy, the rows :func:`colour_step` reads.
INTAKE_BYTES_PER_PIXEL = 16


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
    """The photographs in ``folder``, sorted by name, each once; an error when there are none,
    when the folder holds photographs of a type that is not read, or two whose names differ only
    in case or extension. A byte-identical copy under a second name is named and left out."""
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
    files = _once(files)
    by_stem = collections.defaultdict(list)
    for f in files:
        by_stem[os.path.splitext(os.path.basename(f))[0].lower()].append(f)
    for same in by_stem.values():
        if len(same) > 1:
            raise ReneusError(f"{' and '.join(same)}: two photographs whose names differ only in case or "
                              'extension (two cards, or a camera and a phone?); expected one name per '
                              'photograph: rename one of them')
    return files


def _once(files: list[str]) -> list[str]:
    """``files`` without the byte-identical copies of an earlier one (named in a warning): the
    same photograph twice would count twice."""
    by_size = collections.defaultdict(list)
    for f in files:
        by_size[os.path.getsize(f)].append(f)
    first, copies = {}, []
    for same in by_size.values():
        if len(same) < 2:
            continue
        for f in same:
            with open(f, 'rb') as stream:
                digest = hashlib.file_digest(stream, 'sha256').hexdigest()
            if digest in first:
                copies.append((f, first[digest]))
            else:
                first[digest] = f
    if copies:
        warnings.warn('the same photograph under two names, used once: ' + ', '.join(
            f'{os.path.basename(f)} (a copy of {os.path.basename(original)})' for f, original in copies))
    dropped = {f for f, _ in copies}
    return [f for f in files if f not in dropped]


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
    """The photograph as (H,W,3) uint8 RGB, whole: a truncated or corrupt file (a JPEG whose
    data libjpeg finds anything wrong with included), a CMYK one, samples that are not 8- or
    16-bit are refused by name."""
    try:
        with open(photo.path, 'rb') as f:
            data = f.read()
        rgb = _decode_jpeg(photo.path, data) if data[:3] == b'\xff\xd8\xff' else _decode_other(photo.path)
    except ReneusError:
        raise
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError) as e:
        raise ReneusError(f'{photo.path}: damaged photograph ({e}); expected the whole file as the camera wrote '
                          'it (copy it again from the card, or move it out of the folder)') from None
    if photo.turn:
        rgb = np.asarray(Image.fromarray(rgb).transpose(_SWAPPING[photo.orientation]))
    return rgb


def _decode_jpeg(path: str, data: bytes) -> np.ndarray:
    """A JPEG decoded strictly: libjpeg's warnings (corrupt entropy data, extraneous bytes, a
    premature end) raise ValueError, and so does the colour step that damage leaves when the
    decoder falls back into step without a warning (:func:`colour_step`)."""
    _, _, colorspace, subsampling = simplejpeg.decode_jpeg_header(data)
    if colorspace == 'CMYK':
        raise _cmyk(path)
    rgb = simplejpeg.decode_jpeg(data, colorspace='RGB', strict=True)
    step, y, x = colour_step(rgb, subsampling)
    if step:
        raise ValueError(f'its colours step by {step:.0f} levels at row {y}, from column {x} on, along the '
                         "JPEG's blocks: data altered after the camera wrote it")
    return rgb


#: Pixel size (width, height) of a JPEG's minimum coded unit, by chroma subsampling.
_MCU = {'444': (8, 8), '422': (16, 8), '420': (16, 16), '440': (8, 16), '411': (32, 8), '441': (8, 32),
        'Gray': (8, 8)}
#: The least step (8-bit levels) of a JPEG's colours that damage leaves and :func:`colour_step`
#: refuses (see its measurement in tests/commands/test_bad_inputs.py).
STEP_LEVELS = 3.0
#: Each side of the step, and each side that must show none, spans at least this share of
#: the width: a step caught nearer a row's end is not told from a photograph's own edges.
STEP_SIDE = 1.0 / 8.0


def colour_step(rgb: np.ndarray, subsampling: str) -> tuple[float, int, int]:
    """The step of a JPEG's colours left where its data was damaged (0, and no place, if none).

    Without restart markers a JPEG codes each block's mean colour as the change from the block
    before; Huffman codes fall back into step a few bytes after damage, so libjpeg decodes on
    without a warning, but every block after it keeps the wrong mean. Its colours then step by
    one constant along the top edge of the MCU row r of the damage, right of the column x0 where
    it happened, and along the top edge of row r + 1 left of x0; nowhere else. Per MCU, the step
    between the two pixel rows either side of each MCU row's top edge; a step is refused when
    both of those stretches step alike (their medians, per YCbCr channel) and the two that
    complete their rows do not. A photograph's own straight edge along one MCU row's top edge
    steps across the whole row, not from one row to the next at x0.
    """
    w_mcu, h_mcu = _MCU.get(subsampling, (16, 16))
    h, w = rgb.shape[:2]
    nx = w // w_mcu
    side = max(1, int(np.ceil(STEP_SIDE * nx)))
    ys = np.arange(h_mcu, h - 1, h_mcu)
    if nx < 2 * side or len(ys) < 2:
        return 0.0, 0, 0
    # Only the rows it needs, in YCbCr (the JPEG's own components), as floats.
    rows = cv2.cvtColor(rgb[np.concatenate([ys - 2, ys - 1, ys, ys + 1])], cv2.COLOR_RGB2YCrCb)
    above2, above1, below0, below1 = rows.astype(np.float32).reshape(4, len(ys), w, 3)
    steps = np.median(((below0 + below1 - above1 - above2) * 0.5)[:, :nx * w_mcu]
                      .reshape(len(ys), nx, w_mcu, 3), axis=2)          # (rows, MCUs, channels)
    best = (0.0, 0, 0)
    for x0 in range(side, nx - side + 1, max(1, side // 2)):
        right, left = np.median(steps[:-1, x0:], axis=1), np.median(steps[1:, :x0], axis=1)
        rest = np.maximum(np.abs(np.median(steps[:-1, :x0], axis=1)), np.abs(np.median(steps[1:, x0:], axis=1)))
        alike = np.where(np.sign(right) == np.sign(left), np.minimum(np.abs(right), np.abs(left)), 0.0)
        alike = np.where(rest < 0.5 * alike, alike, 0.0).max(axis=1)
        r = int(np.argmax(alike))
        if alike[r] > best[0]:
            best = (float(alike[r]), int(ys[r]), x0 * w_mcu)
    return best if best[0] >= STEP_LEVELS else (0.0, 0, 0)


def _decode_other(path: str) -> np.ndarray:
    """A PNG or TIFF through Pillow (which raises on a truncated or corrupt file)."""
    guard, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        with Image.open(path) as image:
            if image.mode == 'CMYK':
                raise _cmyk(path)
            image.load()
            if image.mode in _GREY16:
                grey = (np.asarray(image, np.uint16) >> 8).astype(np.uint8)
                return np.repeat(grey[..., None], 3, axis=2)
            if image.mode not in ('1', 'L', 'LA', 'P', 'PA', 'RGB', 'RGBA'):
                raise ReneusError(f'{path}: photograph with {image.mode} samples; expected 8- or 16-bit '
                                  'grey or RGB')
            return np.asarray(image.convert('RGB'))
    finally:
        Image.MAX_IMAGE_PIXELS = guard


def _cmyk(path: str) -> ReneusError:
    return ReneusError(f'{path}: a CMYK photograph (a print format); expected RGB as a camera writes it: '
                       'export it again as sRGB')


#: Photographs decoded at once (each holds its full-size pixels while it is worked on).
WORKERS = max(1, min(4, os.cpu_count() or 1))


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

    Held at once: every photograph's reduced 8-bit copy (``kept``), every whole view it works
    on (``out_size``: float32 RGB, the undistorted and the normalised copy) and, per worker,
    one photograph being decoded.
    """
    width, height = size
    w, h = out_size
    need = n * (kept[0] * kept[1] * 3 + w * h * 3 * 4 * 2) + workers * width * height * INTAKE_BYTES_PER_PIXEL
    limits.check_memory(need, f'{n} photographs of {width}x{height} scaled to {w}x{h} '
                              '(lower it with --max-size N or --downscale F)')
