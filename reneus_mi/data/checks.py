"""Does every camera see the container it is said to see?

Mis-posed data trains anyway, or dies deep inside Dr.Jit, unless it is caught
when it loads. The checks here compare each view with the container mesh,
which is the one thing of the scene known in world coordinates:

- the camera lies outside the container;
- the container's centre is in front of the camera (camera-space z > 0:
  OpenCV axes; a pose given in the OpenGL convention, or a world-to-camera
  matrix given as camera-to-world, fails here) and projects into the image,
  with a margin of :data:`FRAME_MARGIN` of the image size;
- the container is not tiny or far away: its projection spans at least
  :data:`MIN_EXTENT` of the image;
- a mask read from a file agrees with the container's projection (IoU at
  least :data:`MIN_MASK_IOU`), which catches a view paired with another's
  camera, and does not cover the whole image where the container does not
  (an opaque alpha channel);
- the container file is not written with y up (the default of Blender's exporters)
  for cameras with z up: the masks would fit it loosely, and it would refract wrongly.

Messages name the image file, the view and what was expected.
"""
from __future__ import annotations

import warnings

import mitsuba as mi
import numpy as np

from reneus_mi.data.cameras import pixel_rays
from reneus_mi.data.images import as_float
from reneus_mi.geometry.container import inside
from reneus_mi.geometry.mesh import mitsuba_mesh
from reneus_mi.paper import GAMMA
from reneus_mi.utils.errors import ReneusError

#: The container centre may project this far (fraction of the image size) outside the image.
FRAME_MARGIN = 0.25
#: Smallest apparent diameter of the container, as a fraction of the image's smaller side.
MIN_EXTENT = 0.02
#: Smallest intersection-over-union of a given mask and the container's projection.
MIN_MASK_IOU = 0.5
#: Below this mean IoU of the masks and the container's projection the container is also
#: tried turned from y up to z up; it is refused when that fits better by AXES_MARGIN.
AXES_CHECKED_BELOW, AXES_MARGIN = 0.99, 0.02
#: Pixels per view traced for the mask comparison (a regular subset of the image).
MASK_SAMPLES = 1 << 16
#: Accepted range of the container's index of refraction (glass ~1.5, diamond 2.42).
IOR_RANGE = (1.0, 3.0)
#: What an IOR must be, as the messages say it.
IOR_EXPECTED = f'a number in ({IOR_RANGE[0]:g}, {IOR_RANGE[1]:g}]'


def valid_ior(ior) -> bool:
    """Whether ``ior`` is a number in IOR_RANGE (above its low end, up to its high end)."""
    return not isinstance(ior, bool) and isinstance(ior, (int, float)) and IOR_RANGE[0] < ior <= IOR_RANGE[1]


def check_ior(ior, where: str) -> float:
    """The IOR as a float, or raise unless it is :func:`valid_ior`."""
    if not valid_ior(ior):
        raise ReneusError(f"{where}: 'IOR' is {ior!r}; expected {IOR_EXPECTED} (glass: about 1.5)")
    return float(ior)


def check_views(container, K: np.ndarray, c2w: np.ndarray, height: int, width: int,
                files: list[str], given_masks: dict[int, np.ndarray], mask_sources=None,
                name: str = 'container mesh') -> None:
    """Raise naming the first view whose camera does not see ``container`` (a trimesh).

    ``files`` name the views; ``given_masks`` maps view indices to masks read
    from files (computed ones agree by construction); ``mask_sources[v]`` says
    where view ``v``'s mask was read ('from its alpha channel', 'from FILE'); ``name`` names
    the container in messages.
    """
    vertices = np.asarray(container.vertices, dtype=np.float64)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    origins = c2w[:, :3, 3]
    within = inside(origins, container)
    if within.any():
        v = int(np.argmax(within))
        raise ReneusError(f"{files[v]}: view {v}: the camera at {np.round(origins[v], 4).tolist()} "
                          "is inside the container; expected every camera outside it")
    for v in range(len(K)):
        p = c2w[v, :3, :3].T @ (centre - origins[v])
        if not p[2] > 0:
            raise ReneusError(
                f"{files[v]}: view {v}: the container centre is behind the camera (camera-space "
                f"z = {p[2]:.3g}); expected it in front (OpenCV axes, camera-to-world). A pose in "
                "the OpenGL convention or a world-to-camera matrix looks like this")
        u, w_ = (K[v] @ (p / p[2]))[:2]
        if not (-FRAME_MARGIN * width <= u <= (1 + FRAME_MARGIN) * width
                and -FRAME_MARGIN * height <= w_ <= (1 + FRAME_MARGIN) * height):
            raise ReneusError(
                f"{files[v]}: view {v}: the container centre projects to pixel "
                f"({u:.1f}, {w_:.1f}), outside the {width}x{height} image; expected the camera "
                "to look at the container (is the pose flipped or in another convention?)")
        extent = 2.0 * radius * K[v, 0, 0] / np.linalg.norm(p)
        if extent < MIN_EXTENT * min(width, height):
            raise ReneusError(
                f"{files[v]}: view {v}: the container spans about {extent:.3g} pixels "
                f"(radius {radius:.3g} at distance {np.linalg.norm(p):.3g}); expected at least "
                f"{MIN_EXTENT:.0%} of the image: is the container mesh in the cameras' units?")
    if given_masks:
        _check_masks(container, K, c2w, height, width, files, given_masks, mask_sources, name)


#: A file written with y up (Blender's OBJ and PLY exporters by default: forward -z, up y)
#: taken into a world with z up: (x, y, z) -> (x, -z, y).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.sum(a | b)
    return np.sum(a & b) / union if union else 1.0


def _check_masks(container, K, c2w, height, width, files, given_masks, sources, name) -> None:
    scene = mi.load_dict({'type': 'scene', 'container': mitsuba_mesh(container.vertices, container.faces)})
    stride = max(1, int(np.ceil(np.sqrt(height * width / MASK_SAMPLES))))
    ys, xs = np.mgrid[0:height:stride, 0:width:stride]
    px = np.stack([xs.ravel(), ys.ravel()], axis=1)

    def project(scene, v):
        o, d = pixel_rays(K, c2w, v, px)
        ray = mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32)))
        return np.array(scene.ray_test(ray)).reshape(ys.shape)

    ious = {}
    for v, mask in given_masks.items():
        projected = project(scene, v)
        given = mask[::stride, ::stride]
        source = f' {sources[v]}' if sources else ''
        if given.all() and not projected.all():
            raise ReneusError(
                f"{files[v]}: view {v}: the mask{source} covers the whole image, but the container "
                f"covers {projected.mean():.0%} of it; expected the container's pixels only (an opaque "
                "alpha channel is a mask of everything: save the photographs without alpha, and the "
                "container's projection is the mask)")
        ious[v] = _iou(projected, given)
    mean = float(np.mean(list(ious.values())))
    if mean < AXES_CHECKED_BELOW:
        # A container file written with y up fits the masks of a z-up world loosely (a block is
        # a block from most sides) and would refract wrongly without a word: the axes are
        # named where the turned file fits clearly better.
        turned = container.copy()
        turned.vertices = turned.vertices @ Y_UP_TO_Z_UP.T
        turned_scene = mi.load_dict({'type': 'scene', 'container': mitsuba_mesh(turned.vertices, turned.faces)})
        fit = float(np.mean([_iou(project(turned_scene, v), m[::stride, ::stride])
                             for v, m in given_masks.items()]))
        if fit > mean + AXES_MARGIN:
            raise ReneusError(
                f"{name}: the masks overlap the container's projection by mean IoU {mean:.2f}, and by "
                f"{fit:.2f} with the mesh turned from y up to z up: its file was written with y up "
                "(Blender's OBJ and PLY export default); expected the cameras' axes: export it with up "
                "axis Z and forward axis Y")
    for v, iou in ious.items():
        if iou < MIN_MASK_IOU:
            source = f' {sources[v]}' if sources else ''
            raise ReneusError(
                f"{files[v]}: view {v}: the mask{source} overlaps the container's projection by IoU "
                f"{iou:.2f}; expected at least {MIN_MASK_IOU} (is this image paired with another "
                "view's camera, or the pose wrong?)")


#: A photograph this many times brighter or darker than the median one (its mean linear
#: radiance) is named: a dataset's photographs share one exposure, which the model assumes
#: (a capture measures and normalises each photograph's own).
EXPOSURE_OUTLIER = 1.5
#: An overexposed photograph is clipped where the others are not, so its mean says less than
#: its exposure: one with at least this share of its pixels at white more than the median
#: photograph is named too.
CLIPPED_OUTLIER = 0.05
#: A value this close to 1 is clipped (an 8-bit 255).
CLIPPED = 254.5 / 255.0


def warn_exposure_outliers(images, files: list[str]) -> None:
    """Warn, naming it and the factor, of each photograph whose exposure stands out: its mean
    linear value, or the share of it clipped at white."""
    if len(images) < 3:
        return
    samples = [as_float(image[::4, ::4]) for image in images]
    # The mean: a median flips between a print's black and white with the framing.
    level = np.array([np.mean(sample ** GAMMA) for sample in samples])
    clipped = np.array([np.mean(sample.max(axis=-1) >= CLIPPED) for sample in samples])
    typical = np.median(level)
    if not typical > 0:
        return
    expected = ('expected one exposure for all (manual exposure), or photographs that state their exposure: '
                'the capture command measures each from the board')
    for factor, share, path in zip(level / typical, clipped - np.median(clipped), files):
        if not 1.0 / EXPOSURE_OUTLIER <= factor <= EXPOSURE_OUTLIER:
            warnings.warn(f'{path}: {factor:.2f}x as bright as the median photograph (mean linear value); {expected}')
        elif share >= CLIPPED_OUTLIER:
            warnings.warn(f'{path}: {share:.0%} more of it clipped at white than of the median photograph '
                          f'(overexposed: {factor:.2f}x as bright in the mean, more in the light); {expected}')
