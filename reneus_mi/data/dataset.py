"""The in-memory dataset: posed photographs of an object inside a container.

Both file formats (:mod:`reneus_mi.data.blender`, :mod:`reneus_mi.data.neus_format`)
read into and write from :class:`Dataset`. The ReNeuS-specific facts that
neither format has a field for are stored under the same JSON keys in both:

- ``"IOR"``: the container's index of refraction (a number);
- ``"mesh_outside"``: the container mesh (``.ply``/``.obj``, world
  coordinates), a path relative to the dataset folder;
- ``"mesh_inside"``: the ground-truth object mesh, same rules;
- ``"scale_mat"``: (Blender format only, written by reneus-mi) NeuS's 4x4
  normalisation matrix, so that a NeuS dataset survives a round trip;
- ``"ambient"``: the ambient light C_out measured with the photographs (linear, one number
  or RGB), which the scene writer then uses (``reneus_mi.capture`` writes it);
- ``"absorption"``: the absorption coefficient of the container's medium (amber, tinted
  resin), per unit of the world coordinates (one number or RGB, >= 0), which the scene
  writer gives the container as its interior medium;
- ``"containers"``: a container of nested interfaces (a display case, a jar of alcohol), outermost
  first, each ``{"mesh": FILE, "int_ior": N, "ext_ior": N, "absorption": RGB}`` as Mitsuba's
  ``dielectric`` and ``homogeneous`` medium state them: the first is ``mesh_outside`` (with
  ``IOR`` its int_ior, ``absorption`` its medium's), each ``ext_ior`` the ``int_ior`` of the one
  around it (1 for the first), ``absorption`` optional;
- ``"capture"``: what ``reneus_mi.capture`` knows of the world (:mod:`reneus_mi.capture.writer`):
  ``units`` and ``frame`` of the coordinates, ``board``, the printed board the container
  stands on (:class:`PrintedBoard`), which the scene writer puts into the scene, and
  ``container``, what the capture was told and measured of it (``shape``, ``edge_mm``: a
  block's rounded edges, from which the scene writer sets ``model.render.edge_margin``).
"""
from __future__ import annotations

import dataclasses
import os
import shutil

import cv2
import numpy as np

from reneus_mi.data.cameras import check_c2w, check_K, pixel_rays
from reneus_mi.data.checks import check_ior, check_views, warn_exposure_outliers
from reneus_mi.data.images import as_float, read_image
from reneus_mi.data.masks import container_masks
from reneus_mi.geometry.container import bounding_sphere, load_container, mesh_type
from reneus_mi.utils.errors import ReneusError


#: Gap (mm) between the container's bottom and the board in rendered scenes (the board lies
#: this far into the table): a sheet of paper under glass is never in optical contact, and
#: coplanar surfaces confuse a ray tracer. It must exceed the offset by which Mitsuba (and
#: ``reneus``) start a ray off a surface, (1 + max |p|) x 8.9e-5: 0.027 mm at 300 mm from the
#: board's origin; with 0.01 mm the rays leaving the glass through its bottom started beyond
#: the board and saw the tent below it.
CONTACT_GAP = 0.1


@dataclasses.dataclass(frozen=True)
class Interface:
    """One closed interface of a container (an entry of ``containers`` in transforms.json)."""
    #: Path of its closed mesh (world coordinates).
    mesh: str
    #: The IOR inside it (the one outside is that inside the interface around it).
    ior: float
    #: The absorption inside it (RGB per world unit), if any.
    absorption: np.ndarray | None = None


@dataclasses.dataclass(frozen=True)
class PrintedBoard:
    """The printed board the container stands on, as the photographs measured it: what rays
    leaving the container through its bottom see (``capture.board`` in transforms.json)."""
    #: (h, w) float32 in [0, 1]: the print, 0 ink and 1 paper. Pixel (i, j) covers the board's
    #: x in [j, j+1] / px_per_mm and y in [i, i+1] / px_per_mm (millimetres).
    pattern: np.ndarray
    px_per_mm: float
    #: 4x4: the board's frame (OpenCV's ChArUco frame, z into the table) to the dataset's world.
    to_world: np.ndarray
    #: Linear RGB radiance of the paper and of the ink, at the dataset's exposure.
    white: np.ndarray
    black: np.ndarray

    @property
    def size_mm(self) -> tuple[float, float]:
        """Extent along the board's x (columns) and y (rows)."""
        return self.pattern.shape[1] / self.px_per_mm, self.pattern.shape[0] / self.px_per_mm

    def radiance(self, max_texels: int) -> np.ndarray:
        """(h, w, 3) float32 linear radiance of the print, at most ``max_texels`` along its longer
        side (area-averaged, as a coarser look at the print)."""
        h, w = self.pattern.shape
        scale = min(1.0, max_texels / max(h, w))
        pattern = self.pattern if scale == 1.0 else cv2.resize(
            self.pattern, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
        return (self.black + (self.white - self.black) * pattern[..., None]).astype(np.float32)


@dataclasses.dataclass
class Dataset:
    """Posed photographs, container masks and the container itself.

    Cameras are OpenCV pinholes (see :mod:`reneus_mi.data.cameras`); all
    geometry is in world coordinates, the ones the container mesh is given in.
    """
    #: (N,H,W,3): pixel values as in the photographs (gamma-encoded), as the readers hold them
    #: (:func:`~reneus_mi.data.images.stored`: uint8 where every file had 8 bits, else uint16;
    #: 255 or 65535 is 1) or float32 in [0,1] (a dataset made in memory); :meth:`image` gives
    #: a view as float32.
    images: np.ndarray
    #: (N,H,W) bool: where the container is seen (the paper's M_in).
    masks: np.ndarray
    #: (N,3,3) float64 intrinsics in pixels.
    K: np.ndarray
    #: (N,4,4) float64 camera-to-world, OpenCV axes (x right, y down, z forward).
    c2w: np.ndarray
    #: Image file names, one per view.
    names: list[str]
    #: Folder the dataset was read from.
    root: str
    #: Path of the container mesh (world coordinates), if known.
    container: str | None = None
    #: Container index of refraction, if the dataset states it.
    ior: float | None = None
    #: Path of the ground-truth object mesh, if any.
    gt_mesh: str | None = None
    #: NeuS normalisation (unit sphere -> world), if the data has one.
    scale_mat: np.ndarray | None = None
    #: The ambient light C_out (linear RGB), if the dataset measured it.
    ambient: np.ndarray | None = None
    #: Absorption coefficient of the container's medium (RGB, per world unit), if it has one.
    absorption: np.ndarray | None = None
    #: The interfaces inside the container's outer one, outermost first (a case's inner faces,
    #: a jar's liquid): each with the IOR and the absorption inside it.
    inner: tuple[Interface, ...] = ()
    #: Whether the masks were read from files (segmented photographs) rather than projected
    #: from the container mesh: only such masks say where the container really is.
    masks_measured: bool = False
    #: The printed board the container stands on, if the capture measured one.
    board: PrintedBoard | None = None
    #: Units and frame of the world coordinates, where the dataset states them (a capture:
    #: millimetres in the board's frame).
    units: str | None = None
    frame: str | None = None
    #: The radius of a solid block's rounded edges (world units; 0: sharp), where a capture
    #: states or measured its block (``capture.container``: ``shape`` box or rounded, ``edge_mm``).
    edge: float | None = None

    def __len__(self) -> int:
        return len(self.images)

    def image(self, view: int) -> np.ndarray:
        """(H,W,3) float32 in [0,1]: the photograph of ``view``."""
        return as_float(self.images[view])

    @property
    def height(self) -> int:
        return self.images.shape[1]

    @property
    def width(self) -> int:
        return self.images.shape[2]

    def rays(self, view: np.ndarray, px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World origins and unit directions (M,3) through pixel centres.

        ``view`` (M,) holds view indices (a scalar applies to all), ``px``
        (M,2) integer pixel coordinates x, y; the ray passes through
        ``(x + 0.5, y + 0.5)``.
        """
        return pixel_rays(self.K, self.c2w, view, px)

    def normalization(self) -> tuple[np.ndarray, float]:
        """Centre and radius of the sphere the field lives in.

        From ``scale_mat`` when the data has one, else the bounding sphere of the space that
        holds the specimen: the container, or the innermost of its interfaces (a case's air,
        a jar's liquid).
        """
        if self.scale_mat is not None:
            return np.array(self.scale_mat[:3, 3], dtype=np.float64), float(self.scale_mat[0, 0])
        if self.container is not None:
            return bounding_sphere(self.inner[-1].mesh if self.inner else self.container)
        raise ReneusError(f"{self.root}: dataset has neither a NeuS scale_mat nor a container "
                         "mesh, so the region to reconstruct is unknown")

    def pixel_footprint(self) -> float:
        """The world size of one pixel at the centre of the field's sphere, the median over the
        views (its depth in each camera over the focal length): the finest detail the
        photographs show of the specimen."""
        centre, _ = self.normalization()
        w2c = np.linalg.inv(self.c2w)
        depth = w2c[:, 2, :3] @ centre + w2c[:, 2, 3]
        focal = 0.5 * (self.K[:, 0, 0] + self.K[:, 1, 1])
        return float(np.median(np.abs(depth) / focal))

    def validate(self) -> None:
        """Raise ``ValueError`` unless every array has the documented shape and type."""
        n = len(self.images)
        if self.images.ndim != 4 or self.images.shape[-1] != 3 or n == 0:
            raise ReneusError(f"{self.root}: images: expected shape (N,H,W,3) with N > 0, "
                             f"got {self.images.shape}")
        if self.images.dtype not in (np.uint8, np.uint16, np.float32):
            raise ReneusError(f"{self.root}: images: expected dtype uint8, uint16 or float32, got {self.images.dtype}")
        if self.images.dtype == np.float32 and not np.all((self.images >= 0) & (self.images <= 1)):
            raise ReneusError(f"{self.root}: images: expected values in [0, 1]")
        expected = {'masks': (self.masks, self.images.shape[:3]), 'K': (self.K, (n, 3, 3)),
                    'c2w': (self.c2w, (n, 4, 4))}
        for field, (value, shape) in expected.items():
            if np.shape(value) != shape:
                raise ReneusError(f"{self.root}: {field}: expected shape {shape}, "
                                 f"got {np.shape(value)}")
        if self.masks.dtype != bool:
            raise ReneusError(f"{self.root}: masks: expected dtype bool, got {self.masks.dtype}")
        if len(self.names) != n or len(set(self.names)) != n:
            raise ReneusError(f"{self.root}: names: expected {n} distinct names, got {self.names}")
        for i in range(n):
            check_K(self.K[i], f"{self.root}: K[{i}]")
            check_c2w(self.c2w[i], f"{self.root}: c2w[{i}]")
        if self.scale_mat is not None and np.shape(self.scale_mat) != (4, 4):
            raise ReneusError(f"{self.root}: scale_mat: expected shape (4, 4), "
                             f"got {np.shape(self.scale_mat)}")
        if self.ior is not None:
            check_ior(self.ior, f"{self.root}: ior")



def dataset_fingerprint(ds) -> dict:
    """What identifies a dataset's views: their number, size, names and camera centres.

    Stored with a run, it lets ``--resume --data MOVED`` check that the moved
    folder holds the same photographs and cameras.
    """
    return {'views': len(ds), 'width': ds.width, 'height': ds.height, 'names': list(ds.names),
            'centres': [[round(float(x), 5) for x in c] for c in ds.c2w[:, :3, 3]]}


def check_same_dataset(saved: dict, ds, where: str) -> None:
    """Refuse ``ds`` unless it matches the fingerprint ``saved`` of a run's dataset."""
    now = dataset_fingerprint(ds)
    for key in ('views', 'width', 'height', 'names'):
        if saved.get(key) != now[key]:
            raise ReneusError(f'{where}: dataset {ds.root} differs from the run\'s ({key}: '
                              f'{_short(now[key])}, the run had {_short(saved.get(key))}); '
                              'expected the same photographs')
    if not np.allclose(saved['centres'], now['centres'], atol=1e-4):
        raise ReneusError(f"{where}: dataset {ds.root} has other camera positions than the run's; "
                          'expected the same cameras')


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + '...'


def read_extras(meta: dict, root: str, where: str) -> dict:
    """Parse the ReNeuS keys of a metadata dict (see the module docstring)."""
    out = {}
    if meta.get('IOR') is not None:
        out['ior'] = check_ior(meta['IOR'], where)
    for key, field in (('mesh_outside', 'container'), ('mesh_inside', 'gt_mesh')):
        if meta.get(key) is not None:
            out[field] = _mesh_path(meta[key], root, f"{where}: '{key}'")
    if 'scale_mat' in meta:
        scale_mat = np.asarray(meta['scale_mat'], dtype=np.float64)
        if scale_mat.shape != (4, 4):
            raise ReneusError(f"{where}: 'scale_mat' must be a 4x4 matrix, got {meta['scale_mat']!r}")
        out['scale_mat'] = scale_mat
    if meta.get('ambient') is not None:
        out['ambient'] = _rgb(meta['ambient'], lambda v: v > 0, f"{where}: 'ambient'",
                              'a positive radiance (one number or RGB)')
    if meta.get('absorption') is not None:
        out['absorption'] = _rgb(meta['absorption'], lambda v: v >= 0, f"{where}: 'absorption'",
                                 'an absorption coefficient >= 0 per world unit (one number or RGB)')
    if meta.get('containers') is not None:
        out.update(_read_containers(meta['containers'], out, root, f"{where}: 'containers'"))
    if meta.get('capture') is not None:
        out.update(_read_capture(meta['capture'], root, f'{where}: capture'))
    return out


def _mesh_path(rel, root: str, where: str) -> str:
    if not isinstance(rel, str):
        raise ReneusError(f"{where} must be a path string, got {rel!r}")
    path = os.path.normpath(os.path.join(root, rel))
    mesh_type(path)
    if not os.path.isfile(path):
        raise ReneusError(f"{where} names {path}, which does not exist")
    return path


def _ior(value, where: str) -> float:
    """An IOR on one side of an inner interface: air (1) allowed, as in a display case."""
    if value == 1.0 and not isinstance(value, bool):
        return 1.0
    return check_ior(value, where)


def _read_containers(entries, outer: dict, root: str, where: str) -> dict:
    """The container's interfaces (see the module docstring), checked against ``outer`` (the
    keys already read: ``mesh_outside``, ``IOR``, ``absorption`` describe the first)."""
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise ReneusError(f'{where}: expected a list of interfaces, outermost first, each '
                          '{"mesh", "int_ior", "ext_ior", "absorption"}')
    read, outside = [], 1.0
    for i, entry in enumerate(entries):
        at = f'{where}[{i}]'
        unknown = set(entry) - {'mesh', 'int_ior', 'ext_ior', 'absorption'}
        if unknown or 'mesh' not in entry or 'int_ior' not in entry:
            raise ReneusError(f"{at}: keys {sorted(entry)}; expected 'mesh', 'int_ior', optionally 'ext_ior' "
                              "and 'absorption'")
        mesh = _mesh_path(entry['mesh'], root, f'{at}.mesh')
        inside = _ior(entry['int_ior'], f'{at}.int_ior')
        ext = _ior(entry.get('ext_ior', outside), f'{at}.ext_ior')
        if abs(ext - outside) > 1e-6:
            raise ReneusError(f'{at}: ext_ior {ext:g}, but the IOR around it is {outside:g} '
                              f"({'air' if i == 0 else f'containers[{i - 1}].int_ior'}); expected the same")
        absorption = None if entry.get('absorption') is None else _rgb(
            entry['absorption'], lambda v: v >= 0, f'{at}.absorption',
            'an absorption coefficient >= 0 per world unit (one number or RGB)')
        read.append((mesh, inside, absorption))
        outside = inside
    mesh, ior, absorption = read[0]
    for key, given, value in (('mesh_outside', outer.get('container'), mesh), ('IOR', outer.get('ior'), ior)):
        if given is not None and given != value:
            raise ReneusError(f"{where}[0]: {value!r}, but '{key}' says {given!r}; expected the same")
    if outer.get('absorption') is not None:
        if absorption is not None and not np.allclose(outer['absorption'], absorption):
            raise ReneusError(f"{where}[0].absorption differs from 'absorption'; expected the same")
        absorption = outer['absorption']
    return {'container': mesh, 'ior': ior, 'absorption': absorption,
            'inner': tuple(Interface(m, n, a) for m, n, a in read[1:])}


def _rgb(value, ok, where: str, expected: str) -> np.ndarray:
    """One number or three as an RGB array, each finite and ``ok``."""
    rgb = None
    if np.size(value) in (1, 3):
        try:
            rgb = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()
        except (TypeError, ValueError):
            rgb = None
    if rgb is None or not np.all(np.isfinite(rgb)) or not np.all(ok(rgb)):
        raise ReneusError(f'{where} is {value!r}; expected {expected}')
    return rgb


def _read_capture(capture, root: str, where: str) -> dict:
    """The units, frame, block's edge radius and printed board of a ``capture`` entry (see the
    module docstring)."""
    if not isinstance(capture, dict):
        raise ReneusError(f'{where}: expected an object with units, frame and board, got {capture!r}')
    out = {key: capture[key] for key in ('units', 'frame') if isinstance(capture.get(key), str)}
    container = capture.get('container')
    if isinstance(container, dict) and container.get('shape') in ('box', 'rounded'):
        edge = container.get('edge_mm') or 0.0
        if not (isinstance(edge, (int, float)) and np.isfinite(edge) and edge >= 0):
            raise ReneusError(f'{where}.container.edge_mm: {edge!r}; expected a radius >= 0 in millimetres')
        out['edge'] = float(edge) if container.get('shape') == 'rounded' else 0.0
    board = capture.get('board')
    if board is None:
        return out
    where = f'{where}.board'
    try:
        pattern, px = str(board['pattern']), float(board['px_per_mm'])
        to_world = np.asarray(board['to_world'], np.float64).reshape(4, 4)
        white, black = (np.broadcast_to(np.asarray(board[k], np.float64), (3,)).copy() for k in ('white', 'black'))
    except (KeyError, TypeError, ValueError) as e:
        raise ReneusError(f"{where}: {e!r}; expected 'pattern' (an image file), 'px_per_mm', 'to_world' "
                          "(4x4), 'white' and 'black' (linear RGB)") from None
    if not (px > 0 and np.all(np.isfinite(to_world)) and np.all(black >= 0) and np.all(white > black)):
        raise ReneusError(f'{where}: px_per_mm {px}, white {white.tolist()}, black {black.tolist()}; expected '
                          'px_per_mm > 0, a finite to_world and the paper brighter than the ink (>= 0)')
    image, _ = read_image(os.path.normpath(os.path.join(root, pattern)))
    out['board'] = PrintedBoard(pattern=image.mean(axis=-1), px_per_mm=px, to_world=to_world,
                                white=white, black=black)
    return out


def write_extras(ds: Dataset, out_dir: str) -> dict:
    """Copy the dataset's meshes into ``out_dir``; return the ReNeuS keys naming them."""
    meta = {}
    if ds.ior is not None:
        meta['IOR'] = float(ds.ior)
    if ds.ambient is not None:
        meta['ambient'] = np.asarray(ds.ambient, np.float64).tolist()
    if ds.absorption is not None:
        meta['absorption'] = np.asarray(ds.absorption, np.float64).tolist()
    for key, path, stem in (('mesh_outside', ds.container, 'container'),
                            ('mesh_inside', ds.gt_mesh, 'gt_mesh')):
        if path is not None:
            meta[key] = _copy_into(path, out_dir, stem)
    if ds.inner:
        inner = [Interface(_copy_into(i.mesh, out_dir, f'container_inner_{k + 1}'), i.ior, i.absorption)
                 for k, i in enumerate(ds.inner)]
        meta['containers'] = containers_json(Interface(meta['mesh_outside'], ds.ior, ds.absorption), inner)
    return meta


def containers_json(outer: Interface, inner) -> list[dict]:
    """The ``containers`` entry of transforms.json (see the module docstring) of the interfaces
    ``outer`` (the container's own) and ``inner``, their meshes named relative to the dataset."""
    entries, outside = [], 1.0
    for interface in (outer, *inner):
        entry = {'mesh': interface.mesh, 'int_ior': float(interface.ior), 'ext_ior': outside}
        if interface.absorption is not None:
            entry['absorption'] = np.asarray(interface.absorption, np.float64).tolist()
        entries.append(entry)
        outside = float(interface.ior)
    return entries


def _copy_into(path: str, out_dir: str, stem: str) -> str:
    """Copy a mesh into ``out_dir`` as ``stem`` with its extension; return its new name."""
    name = stem + os.path.splitext(path)[1].lower()
    target = os.path.join(out_dir, name)
    if not (os.path.exists(target) and os.path.samefile(path, target)):
        shutil.copyfile(path, target)
    return name


def check_writable(ds: Dataset, out_dir: str) -> None:
    """Validate ``ds`` and its meshes before anything is written to ``out_dir``."""
    ds.validate()
    stems = [os.path.splitext(name)[0] for name in ds.names]
    if len(set(stems)) != len(stems):
        raise ReneusError(f"{ds.root}: names: image names must differ without their extension, "
                         f"got {ds.names}")
    for path in (ds.container, ds.gt_mesh):
        if path is not None:
            mesh_type(path)
            if not os.path.isfile(path):
                raise ReneusError(f"{path}: mesh file is missing")
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise ReneusError(f"{out_dir}: expected a folder to write the dataset into, found a file")


def _stack(images: list[np.ndarray]) -> np.ndarray:
    """Images as :func:`~reneus_mi.data.images.stored` holds them, in one array of one type: 8 bits
    where all are, else 16; float32 where any is float (made in memory)."""
    types = {image.dtype for image in images}
    if types <= {np.dtype(np.uint8), np.dtype(np.uint16)}:
        if len(types) == 1:
            return np.stack(images)
        return np.stack([image.astype(np.uint16) * np.uint16(257) if image.dtype == np.uint8 else image
                         for image in images])
    return np.stack([as_float(image) for image in images])


def assemble(*, images: list[np.ndarray], masks: list[np.ndarray | None], K: np.ndarray,
             c2w: np.ndarray, names: list[str], files: list[str], root: str, meta_file: str,
             need_container: bool, container: str | None = None, ior: float | None = None,
             gt_mesh: str | None = None, scale_mat: np.ndarray | None = None,
             ambient: np.ndarray | None = None, absorption: np.ndarray | None = None,
             inner: tuple[Interface, ...] = (), board: PrintedBoard | None = None, units: str | None = None,
             frame: str | None = None, edge: float | None = None, mask_sources: list[str] | None = None) -> Dataset:
    """Check what a reader found and build the :class:`Dataset`.

    ``files`` are the image paths (for messages); ``masks`` may hold None for
    views without one: those are projected from the container, or are all
    True when there is no container. ``mask_sources`` say where each view's mask
    came from (for messages). ``meta_file`` is named when the container is missing.
    """
    height, width = images[0].shape[:2]
    for img, path in zip(images, files):
        if img.shape[:2] != (height, width):
            raise ReneusError(f"{path}: image is {img.shape[1]}x{img.shape[0]}, but "
                             f"{files[0]} is {width}x{height}; all images must have one size")
    for mask, path in zip(masks, files):
        if mask is not None and mask.shape != (height, width):
            raise ReneusError(f"mask of {path}: is {mask.shape[1]}x{mask.shape[0]}, "
                             f"expected the image size {width}x{height}")
    if board is None:    # a capture's photographs had their exposures measured and normalised
        warn_exposure_outliers(images, files)
    if container is None and need_container:
        raise ReneusError(f"{meta_file}: dataset has no container mesh "
                         "(expected a 'mesh_outside' entry naming its mesh file)")
    for interface in inner:
        load_container(interface.mesh)
    if container is not None:
        check_views(load_container(container), np.asarray(K), np.asarray(c2w), height, width,
                    files, {i: m for i, m in enumerate(masks) if m is not None}, mask_sources, name=container)
    missing = [i for i, m in enumerate(masks) if m is None]
    if missing:
        if container is not None:
            computed = container_masks(container, K, c2w, height, width, missing)
        else:
            computed = np.ones((len(missing), height, width), bool)
        for i, m in zip(missing, computed):
            masks[i] = m
    ds = Dataset(images=_stack(images), masks=np.stack(masks),
                 K=np.asarray(K, np.float64), c2w=np.asarray(c2w, np.float64), names=list(names),
                 root=root, container=container, ior=ior, gt_mesh=gt_mesh, scale_mat=scale_mat,
                 ambient=ambient, absorption=absorption, inner=inner, masks_measured=not missing, board=board,
                 units=units, frame=frame, edge=edge)
    ds.validate()
    return ds
