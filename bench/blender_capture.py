"""A museum-style capture rendered by a second renderer: Blender Cycles photographs a specimen
in a glass block standing on a printed ChArUco board, to test ``python -m reneus_mi.capture``
on photographs the project did not render itself.

It is the Cycles twin of ``reneus_mi/capture/simulation.py`` and writes the same layout: the
photographer's folder ``PHOTOS`` (``IMG_0001.jpg`` ... and ``capture.json``, what
:class:`reneus_mi.capture.settings.CaptureSettings` reads) and, apart, ``TRUTH``
(``truth.json`` with simulate.py's keys, plus the renderer and its seconds;
``specimen.ply`` and ``container.ply`` in the board's frame, millimetres). Run with the
Python of a venv that has the ``bpy`` wheel, not the project's::

    python3.11 -m venv /work/venvs/bpy && /work/venvs/bpy/bin/pip install bpy==5.0.1 'numpy<2' \\
        'opencv-contrib-python-headless<4.12'
    /work/venvs/bpy/bin/python bench/blender_capture.py PHOTOS --truth TRUTH [--specimen ant|ant_thin|beetle|shell]
        [--block small|large] [--container box|jar] [--size 960x640] [--board-factor K] [--views 48] [--spp N] [--seed S]
        [--ior 1.45] [--edge-mm R | --bow-mm S] [--preview]
    /work/venvs/bpy/bin/python bench/blender_capture.py PHOTOS --truth TRUTH --check
    /work/venvs/bpy/bin/python bench/blender_capture.py PHOTOS --truth TRUTH --reduce-from SRC_PHOTOS SRC_TRUTH \
        --size 960x640

It imports neither reneus_mi nor mitsuba (the bpy venv has numpy < 2); it borrows the mesh
helpers of ``bench/blender_set.py`` (tubes, limbs, the ant, voxel remesh, the glass block,
Cycles' reset).

The scene, in the board's frame (OpenCV ChArUco: origin at the outer corner of the first
square, x along the columns, y along the rows, z into the table, millimetres; Blender's
world is the same turned 180 degrees about x, so that its z is up):

- the print: OpenCV's pattern (``CharucoBoard.generateImage``) with a white paper margin, a
  diffuse textured plane (albedo 0.8 paper, 0.04 ink, linear) ``CONTACT_GAP`` into the table;
- the light tent: a constant world of radiance 1;
- the block: a W x D x H box of Glass BSDF (roughness 0) standing on the board at a place
  ``(x, y, yaw)`` near its centre; caustics on, so its shadow and caustics fall on the print;
  polished round (``--edge-mm``) or convex (``--bow-mm``) where asked, stated as a sharp box;
  or (``--container jar``) a closed glass jar, a cylinder whose walls, lid and floor are
  ``JAR_WALL_MM`` thick, filled with ethanol (IOR 1.36), its rims sharp, stated to the capture
  as a cylinder with ``wall_mm``, ``liquid_ior`` and ``edge_mm`` 0;
- the specimen: procedural, one watertight surface (voxel remesh), diffuse with a noise
  albedo, hanging at mid-height: ``ant`` (head, thorax, gaster, six jointed legs 0.37-0.53
  mm thick in the small block, elbowed antennae of 0.33 mm), ``ant_thin`` (the same ant with legs
  0.29-0.12 mm thick and antennae of 0.10-0.08 mm, remeshed at 0.014 mm), ``beetle`` (broad oval
  body, six short stout legs), ``shell`` (an ammonite-like coil, no thin parts);
- the cameras: rings of elevations between 20 and 70 degrees, turntable azimuths from a
  random start, a little aim jitter and roll, every third shot in portrait.

Each view is rendered linear (EXR) as a pinhole frame a little larger than the photograph
(with ``--board-factor K``, for 12 megapixels and more: the frame at 1/K of the size, scaled up
(bicubic), and the block's region, with a margin, at full size over it: a camera's pixels where
the specimen is, a softer board, which the calibration measures all the same), then gets what a
camera does, in numpy/OpenCV as simulate.py does it: lens distortion
(k1, k2, p1, p2, k3) around an off-centre principal point, an exposure that drifts between
shots, shot and read noise, the display curve (gamma 2.2) and JPEG. Pixel coordinates follow
reneus-mi: the centre of the top-left pixel is at (0.5, 0.5), also in ``truth.json``'s K.

``--check`` (also run after every render, its figures in truth.json): the ChArUco corners
found in each JPEG against the truth's projection of the print's corners, those seen
through the air only.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import blender_set as bs  # noqa: E402  (exits with a hint without bpy)
import bmesh  # noqa: E402
import bpy  # noqa: E402
import cv2  # noqa: E402
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402

#: Blocks: outer size W x D x H (mm) and the board printed for them (columns x rows squares,
#: square and marker side in mm). A board about six times the block's width, like simulate.py's.
BLOCKS = {
    'small': dict(size_mm=(40.0, 30.0, 22.0), squares=(10, 7), square_mm=24.0, marker_mm=18.0),
    'large': dict(size_mm=(60.0, 45.0, 30.0), squares=(12, 9), square_mm=25.0, marker_mm=19.0),
}
#: Jars (``--container jar``) on the same boards: outer diameter x diameter x height (mm), as
#: the capture states a cylinder; glass walls, lid and floor JAR_WALL_MM thick around ethanol.
JARS = {'small': (40.0, 40.0, 30.0), 'large': (60.0, 60.0, 40.0)}
JAR_WALL_MM = 2.0
LIQUID_IOR = 1.36
#: Facets of a quarter circle of a rounded block's edge (``--edge-mm``).
EDGE_SEGMENTS = 12
#: Cuts of each edge of a bowed block (``--bow-mm``): 0.8 mm facets on the small block's 40 mm
#: side, whose normals differ by 0.1 degrees at a bow of 0.3 mm (flat-shaded, as cut).
BOW_CUTS = 48
#: The capture's name of each container's shape.
SHAPES = {'box': 'box', 'jar': 'cylinder'}
#: Sides of the jar's cylinder (Blender's primitive and the truth's mesh alike).
JAR_SIDES = 64
#: ArUco dictionary of the markers (35 or 54 markers used of 100).
DICTIONARY = 'DICT_4X4_100'
#: White paper around the printed pattern (mm).
PAPER_MARGIN_MM = 15.0
#: Resolution of the print's texture: a square of the photographs covers 0.3 mm or more.
TEXTURE_PX_PER_MM = 10.0
#: Linear albedo of the paper and of the ink.
PAPER_WHITE, INK_BLACK = 0.8, 0.04
#: Radiance of the light tent (linear): uniform, as the project's model assumes.
AMBIENT = 1.0
#: Gap (mm) between the block's bottom and the print (reneus_mi.data.dataset.CONTACT_GAP).
CONTACT_GAP = 0.1
#: Index of refraction of the block (--ior).
IOR = 1.45
#: Specimen length (its largest extent) as a share of the block's width: 12 mm in the 40 mm
#: block, 18 mm in the 60 mm one.
SPECIMEN_SHARE = 0.3
#: Yaw of the specimen relative to the block (degrees): not square to its walls.
SPECIMEN_YAW = 14.0
#: Least gap between the specimen's bounding box and each wall, as a share of the block's
#: smallest side (the build refuses a specimen that comes closer).
CLEARANCE = 0.1
#: The block's place: footprint centre within this share of the board's size from its centre.
POSE_JITTER = 0.05
#: The block's yaw is drawn from this range (degrees): never square to the board.
YAW_RANGE = (10.0, 40.0)

#: Default photograph size (--size).
SIZE = (960, 640)
#: Focal length as a multiple of the image width (a normal lens).
FOCAL_SHARE = 1.2
#: Principal point minus the image centre, as a share of the width (+7.5, -5.1 px at 960).
PRINCIPAL_OFFSET = (0.0078, -0.0053)
#: OpenCV's k1, k2, p1, p2, k3 (mild barrel).
DISTORTION = (-0.1, 0.05, 0.0006, -0.0004, 0.0)
#: Rings of the hemisphere (degrees above the board), each jittered by +- ELEVATION_JITTER;
#: views are shared among them in proportion to the ring's circumference.
ELEVATIONS = (23.0, 37.0, 51.0, 65.0)
ELEVATION_JITTER = 3.0
#: Camera distance: the board's longer side, face on, spans this share of the image width
#: (simulate.py: 0.69); the block then spans about a fifth of it and every photograph still
#: shows 30-50 of the board's corners.
BOARD_SPAN = 0.95
#: Relative jitter of each camera's distance.
DISTANCE_JITTER = 0.05
#: Aim jitter, as a share of the block's width (8 mm for simulate.py's 50 mm block), and roll.
AIM_JITTER = 0.16
ROLL_JITTER_DEG = 3.0
#: Every this many shots the camera is turned to portrait, alternately left and right.
PORTRAIT_EVERY = 3
#: Camera gain (linear radiance x gain = sensor value): the paper at about 0.68.
EXPOSURE = 0.85
#: Each shot's gain is EXPOSURE x (1 + U(-j, j)).
EXPOSURE_JITTER = 0.15
#: Sensor noise variance: READ_NOISE^2 + SHOT_NOISE x value (linear), as simulate.py's.
READ_NOISE, SHOT_NOISE = 0.002, 0.0004
#: Display curve of the JPEGs.
GAMMA = 2.2
JPEG_QUALITY = 90
#: Views of --preview, spread over the rings (the last a portrait shot).
PREVIEW_VIEWS = 4

#: Cycles: samples per pixel at most (adaptive) and the noise level where a pixel stops.
#: Measured at 960x640 (ant, small block, one view), CPU seconds: 32 spp 14.5, 64 spp 22.5
#: (OIDN 'HIGH' at 32: 26). The whole capture, 48 views at 48 spp: 21.8 s a view, 17.5
#: minutes, with another job busy on the two cores (alone: about 2/3 of that). The board
#: seen through the glass keeps speckles even at 64 spp without the 'ACCURATE' prefilter;
#: sensor noise (0.017 on the paper) exceeds the render's (0.004 at 32 spp) anyway.
SPP = 48
ADAPTIVE_THRESHOLD = 0.02
#: OpenImageDenoise's quality: 'BALANCED' is half the time of 'HIGH', alike to the eye here.
DENOISING_QUALITY = 'BALANCED'
#: Threads of Cycles (the machine has two cores, shared).
THREADS = 2
#: Light paths: glass needs long specular chains; the print is lit through the block.
MAX_BOUNCES, DIFFUSE_BOUNCES, SPECULAR_BOUNCES = 12, 3, 12

#: --check leaves out corners whose refinement window comes within this many pixels of the
#: block's outline (the project's capture: 3 px from the container's projection).
CHECK_MARGIN_PX = 2.0

#: Board frame -> Blender world (a half turn about x); also Blender camera -> OpenCV camera.
FLIP = np.diag([1.0, -1.0, -1.0, 1.0])


# --- specimens (numpy parts, unit size; x forward, z up) -----------------------------------

def beetle(limbs: list | None = None):
    """A broad oval body (elytra, pronotum, head) on six short stout legs, short antennae."""
    parts = [bs.ellipsoid((-0.12, 0.0, 0.06), (0.32, 0.23, 0.13), rings=24),
             bs.ellipsoid((0.23, 0.0, 0.05), (0.11, 0.18, 0.09)),
             bs.ellipsoid((0.37, 0.0, 0.03), (0.07, 0.10, 0.06))]
    for side in (-1.0, 1.0):
        for x, reach in ((-0.2, -0.12), (0.0, -0.02), (0.2, 0.1)):
            a = np.array([x, side * 0.12, -0.02])
            knee = a + [0.4 * reach, side * 0.17, -0.02]
            foot = knee + [0.6 * reach, side * 0.08, -0.13]
            parts += bs.limb([a, knee, foot], [0.05, 0.042, 0.035])
        parts += bs.limb([np.array([0.42, side * 0.05, 0.05]), np.array([0.48, side * 0.12, 0.07]),
                       np.array([0.55, side * 0.16, 0.05])], [0.025, 0.022, 0.03])
    return parts


def shell(limbs: list | None = None):
    """An ammonite-like coil: a tube along a logarithmic spiral in the xz plane (each whorl
    twice the last, the tube 0.42 of the radius: the whorls overlap), capped by a ball."""
    theta = np.linspace(0.0, 3.5 * 2 * np.pi, 420)
    r = 0.044 * 2.0 ** (theta / (2 * np.pi))
    pts = np.stack([r * np.cos(theta), 0.0 * theta, r * np.sin(theta)], 1)
    tube_r = 0.42 * r
    return [bs.tube(pts, tube_r, sides=28), bs.sphere(pts[-1], 0.98 * tube_r[-1], rings=14)]


#: Specimens: parts, albedo palette (linear RGB, noise value 0 -> 1) and, where the parts are
#: thinner than blender_set's VOXEL keeps, the remesh's voxel (unit).
SPECIMENS = {
    'ant': dict(make=bs.ant, palette=((0.10, 0.04, 0.02), (0.40, 0.16, 0.05), (0.65, 0.42, 0.18))),
    'ant_thin': dict(make=lambda limbs=None: bs.ant(limbs, bs.ANT_RADII['ant_thin']), voxel=0.0012,
                     palette=((0.10, 0.04, 0.02), (0.40, 0.16, 0.05), (0.65, 0.42, 0.18))),
    'beetle': dict(make=beetle, palette=((0.03, 0.10, 0.05), (0.15, 0.35, 0.12), (0.55, 0.45, 0.10))),
    'shell': dict(make=shell, palette=((0.35, 0.18, 0.08), (0.72, 0.60, 0.42), (0.88, 0.82, 0.70))),
}


# --- geometry of the capture (numpy, board frame) -------------------------------------------

def look_at(eye, target, up) -> np.ndarray:
    """OpenCV camera-to-world at ``eye`` looking at ``target``, ``up`` up in the image."""
    forward = np.asarray(target, float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, np.cross(forward, right), forward, eye
    return c2w


def pose_matrix(pose) -> np.ndarray:
    """4x4 board-from-block transform of a place ``(x, y, yaw)`` (as the project's)."""
    x, y, yaw = pose
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    M = np.eye(4)
    M[:2, :2] = [[c, -s], [s, c]]
    M[:3, 3] = [x, y, 0.0]
    return M


def ring_counts(views: int) -> list[int]:
    """Views per ring of ELEVATIONS, in proportion to each ring's circumference."""
    weight = np.cos(np.radians(ELEVATIONS))
    share = views * weight / weight.sum()
    counts = np.floor(share).astype(int)
    for k in np.argsort(counts - share)[:views - counts.sum()]:
        counts[k] += 1
    return counts.tolist()


def cameras(rig: dict, rng: np.random.Generator) -> np.ndarray:
    """OpenCV camera-to-board matrices (N,4,4) on the hemisphere above the block."""
    W, _, H = rig['size_mm']
    centre = np.array([rig['pose'][0], rig['pose'][1], -0.5 * H])
    aim = AIM_JITTER * W
    c2ws = []
    for elevation, count in zip(ELEVATIONS, ring_counts(rig['views'])):
        start = rng.uniform(0.0, 360.0 / count)
        for k in range(count):
            azimuth = math.radians(start + 360.0 * k / count)
            e = math.radians(elevation + rng.uniform(-ELEVATION_JITTER, ELEVATION_JITTER))
            d = rig['distance_mm'] * (1.0 + rng.uniform(-DISTANCE_JITTER, DISTANCE_JITTER))
            # Up is -z: the board's z points into the table.
            eye = centre + d * np.array([math.cos(e) * math.cos(azimuth), math.cos(e) * math.sin(azimuth),
                                         -math.sin(e)])
            target = centre + rng.uniform(-aim, aim, 3) * [1.0, 1.0, 0.3]
            c2w = look_at(eye, target, up=(0.0, 0.0, -1.0))
            roll = rng.uniform(-ROLL_JITTER_DEG, ROLL_JITTER_DEG)
            n = len(c2ws)
            if PORTRAIT_EVERY and n % PORTRAIT_EVERY == PORTRAIT_EVERY - 1:
                roll += 90.0 if (n // PORTRAIT_EVERY) % 2 else -90.0
            c, s = math.cos(math.radians(roll)), math.sin(math.radians(roll))
            c2w[:3, :3] = c2w[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            c2ws.append(c2w)
    return np.stack(c2ws)


def intrinsics(width: int, height: int) -> np.ndarray:
    """K of the photographs (reneus-mi pixel convention)."""
    f = FOCAL_SHARE * width
    return np.array([[f, 0.0, 0.5 * width + PRINCIPAL_OFFSET[0] * width],
                     [0.0, f, 0.5 * height + PRINCIPAL_OFFSET[1] * width], [0.0, 0.0, 1.0]])


def _opencv_K(K: np.ndarray) -> np.ndarray:
    """K in OpenCV's pixel convention (the top-left pixel's centre at (0, 0))."""
    K_cv = np.array(K, np.float64)
    K_cv[:2, 2] -= 0.5
    return K_cv


def undistort_points(pixels: np.ndarray, K: np.ndarray, dist) -> np.ndarray:
    """Normalised pinhole coordinates (x/z, y/z) of distorted pixels (reneus-mi convention)."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    out = cv2.undistortPointsIter(np.ascontiguousarray(pixels - 0.5, np.float64).reshape(-1, 1, 2),
                                  _opencv_K(K), np.asarray(dist, np.float64), None, None, criteria)
    return out.reshape(-1, 2)


def pinhole_frame(K: np.ndarray, dist, width: int, height: int) -> tuple[np.ndarray, tuple[int, int]]:
    """K and size of the pinhole frame that covers the photograph's undistorted extent (same
    focal length; the photograph's border undistorted, 2 pixels spare)."""
    t = np.linspace(0.0, 1.0, 64)
    w, h = width, height
    border = np.concatenate([np.c_[t * w, 0 * t], np.c_[t * w, h + 0 * t], np.c_[0 * t, t * h],
                             np.c_[w + 0 * t, t * h]])
    normal = undistort_points(border, K, dist)
    f = K[0, 0]
    lo = np.floor(normal.min(axis=0) * f) - 2
    hi = np.ceil(normal.max(axis=0) * f) + 2
    size = (hi - lo).astype(int)
    return np.array([[f, 0.0, -lo[0]], [0.0, f, -lo[1]], [0.0, 0.0, 1.0]]), (int(size[0]), int(size[1]))


def distortion_maps(K: np.ndarray, dist, K_r: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H,W,2) float32 source positions (OpenCV pixels) in the pinhole frame of each
    photograph pixel: what the lens does, as cv2.remap takes it (simulate.py's distort_image)."""
    ys, xs = np.mgrid[:height, :width]
    pixels = np.stack([xs.ravel(), ys.ravel()], axis=1) + 0.5
    normal = undistort_points(pixels.astype(np.float64), K, dist)
    src = normal * [K_r[0, 0], K_r[1, 1]] + K_r[:2, 2] - 0.5
    return src.reshape(height, width, 2).astype(np.float32)


def expose(linear: np.ndarray, gain: float, rng: np.random.Generator) -> np.ndarray:
    """8-bit RGB of a linear image: gain, sensor noise, the display curve."""
    value = linear * gain
    value = value + rng.normal(size=value.shape) * np.sqrt(READ_NOISE ** 2 + SHOT_NOISE * np.clip(value, 0, None))
    return np.round(np.clip(value, 0.0, 1.0) ** (1.0 / GAMMA) * 255.0).astype(np.uint8)


def container_mesh(shape: str, size_mm, pose) -> tuple[np.ndarray, np.ndarray]:
    """The container's outer surface in the board's frame, triangles wound outwards: the block
    (8 shared vertices) or the jar (a JAR_SIDES-sided cylinder, closed by two fans)."""
    W, D, H = size_mm
    if shape == 'box':
        corners = np.array([[x, y, z] for z in (0.0, -H) for y in (-0.5 * D, 0.5 * D) for x in (-0.5 * W, 0.5 * W)])
        # Index = x + 2 y + 4 z (z = 1: the top, at -H).
        quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
        faces = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    else:
        a = 2.0 * np.pi * np.arange(JAR_SIDES) / JAR_SIDES
        ring = np.stack([0.5 * W * np.cos(a), 0.5 * D * np.sin(a)], axis=1)
        corners = np.concatenate([np.c_[ring, np.zeros(JAR_SIDES)], np.c_[ring, np.full(JAR_SIDES, -H)],
                                  [[0.0, 0.0, 0.0], [0.0, 0.0, -H]]])
        n = JAR_SIDES
        faces = [t for i in range(n) for t in ((i, (i + 1) % n, n + (i + 1) % n), (i, n + (i + 1) % n, n + i))]
        faces += [(2 * n, (i + 1) % n, i) for i in range(n)] + [(2 * n + 1, n + i, n + (i + 1) % n) for i in range(n)]
    V = corners @ pose_matrix(pose)[:3, :3].T + pose_matrix(pose)[:3, 3]
    F = np.array(faces)
    # Convex: each triangle faces away from the centre (z into the table flips 'counter-clockwise').
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    inward = np.einsum('ij,ij->i', n, V[F].mean(axis=1) - V.mean(axis=0)) < 0
    F[inward] = F[inward][:, ::-1]
    return V, F


# --- Blender scene ------------------------------------------------------------------------

def setup_cycles(spp: int) -> bpy.types.Scene:
    """blender_set's Cycles (OIDN, Standard view, caustics on), here: two threads, linear EXR
    output, the light paths of a glass block, the constant tent."""
    sc = bs.reset_blender(spp)
    cy = sc.cycles
    cy.adaptive_threshold = ADAPTIVE_THRESHOLD
    cy.denoising_quality = DENOISING_QUALITY
    cy.max_bounces, cy.diffuse_bounces = MAX_BOUNCES, DIFFUSE_BOUNCES
    cy.glossy_bounces = cy.transmission_bounces = SPECULAR_BOUNCES
    cy.transparent_max_bounces = 8
    cy.caustics_reflective = cy.caustics_refractive = True
    cy.blur_glossy = 0.0
    sc.render.threads_mode, sc.render.threads = 'FIXED', THREADS
    settings = sc.render.image_settings
    settings.file_format, settings.color_mode, settings.color_depth = 'OPEN_EXR', 'RGB', '32'
    settings.exr_codec = 'ZIP'
    sc.world.node_tree.nodes['Background'].inputs['Color'].default_value = (AMBIENT, AMBIENT, AMBIENT, 1.0)
    return sc


def board_pattern(rig: dict) -> np.ndarray:
    """The print's albedo (rows x columns, float32, top row = least board y): OpenCV's pattern
    (its pixel grid that of the board) in a white margin."""
    cols, rows = rig['squares']
    aruco = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, rig['dictionary']))
    board = cv2.aruco.CharucoBoard((cols, rows), rig['square_mm'], rig['marker_mm'], aruco)
    board.setLegacyPattern(False)
    size = (int(round(cols * rig['square_mm'] * TEXTURE_PX_PER_MM)), int(round(rows * rig['square_mm'] * TEXTURE_PX_PER_MM)))
    pattern = board.generateImage(size, marginSize=0, borderBits=1)
    pad = int(round(PAPER_MARGIN_MM * TEXTURE_PX_PER_MM))
    sheet = np.pad(pattern, pad, constant_values=255).astype(np.float32) / 255.0
    return INK_BLACK + (PAPER_WHITE - INK_BLACK) * sheet


def make_board(rig: dict) -> bpy.types.Object:
    """The print as a diffuse quad, ``CONTACT_GAP`` under the block, its albedo a non-colour
    float texture."""
    albedo = board_pattern(rig)
    h, w = albedo.shape
    img = bpy.data.images.new('print', w, h, alpha=False, float_buffer=True)
    img.colorspace_settings.name = 'Non-Color'
    rgba = np.repeat(albedo[::-1, :, None], 4, axis=2)      # Blender's rows run upwards
    rgba[..., 3] = 1.0
    img.pixels.foreach_set(rgba.ravel())
    img.pack()
    # Texture pixel j covers the board's [j - pad, j - pad + 1] / TEXTURE_PX_PER_MM.
    pad = int(round(PAPER_MARGIN_MM * TEXTURE_PX_PER_MM))
    lo, hi = -pad / TEXTURE_PX_PER_MM, ((w - pad) / TEXTURE_PX_PER_MM, (h - pad) / TEXTURE_PX_PER_MM)
    corners_board = [(lo, lo), (hi[0], lo), (hi[0], hi[1]), (lo, hi[1])]
    verts = [(x, -y, -CONTACT_GAP) for x, y in corners_board]
    # Facing Blender's +z (upwards); uv v = 1 at the pattern's top row (board y = lo).
    me = bpy.data.meshes.new('print')
    me.from_pydata(verts, [], [(0, 3, 2, 1)])
    uv = me.uv_layers.new(name='uv')
    for loop in me.loops:
        x, y = corners_board[loop.vertex_index]
        uv.data[loop.index].uv = ((x - lo) / (hi[0] - lo), 1.0 - (y - lo) / (hi[1] - lo))
    mat = bpy.data.materials.new('print')
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    tex = nodes.new('ShaderNodeTexImage')
    tex.image, tex.interpolation, tex.extension = img, 'Linear', 'EXTEND'
    bsdf = nodes.new('ShaderNodeBsdfDiffuse')
    bsdf.inputs['Roughness'].default_value = 0.0
    out = nodes.new('ShaderNodeOutputMaterial')
    links.new(tex.outputs['Color'], bsdf.inputs['Color'])
    links.new(bsdf.outputs['BSDF'], out.inputs['Surface'])
    me.materials.append(mat)
    ob = bpy.data.objects.new('print', me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def make_specimen(rig: dict) -> tuple[np.ndarray, np.ndarray]:
    """The specimen, remeshed, placed in the block at mid-height; its triangles in the board's
    frame. Refuses one that comes closer than CLEARANCE to a wall."""
    spec = SPECIMENS[rig['specimen']]
    limbs = []
    parts = spec['make'](limbs)
    # The limbs' joints move with the parts (inside them, they leave the bounding box alone).
    fitted = bs.fit(parts + [(joints, np.zeros((0, 3), int)) for _, joints, _ in limbs], (0.5, 0.5, 0.5))
    parts, joints = fitted[:len(parts)], [v for v, _ in fitted[len(parts):]]
    ob, V, F = bs.object_mesh(rig['specimen'], parts, spec['palette'], spec.get('voxel', bs.VOXEL))
    W, D, H = rig['size_mm']
    length = SPECIMEN_SHARE * BLOCKS[rig['block']]['size_mm'][0]
    c, s = math.cos(math.radians(SPECIMEN_YAW)), math.sin(math.radians(SPECIMEN_YAW))
    local = np.eye(4)                                         # block frame (board axes) from unit
    local[:3, :3] = np.diag([1.0, -1.0, -1.0]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) * length
    local[:3, 3] = [0.0, 0.0, -0.5 * H]
    inside = V @ local[:3, :3].T + local[:3, 3]
    wall = rig.get('wall_mm', 0.0)
    side_gap = (0.5 * W - wall - np.linalg.norm(inside[:, :2], axis=1).max() if rig['container'] == 'jar'
                else (0.5 * np.array([W, D]) - np.abs(inside[:, :2]).max(axis=0)).min())
    gap = min(side_gap, (-inside[:, 2]).min() - wall, (H + inside[:, 2]).min() - wall)
    if gap < CLEARANCE * min(W, D, H):
        sys.exit(f"error: {rig['specimen']} comes within {gap:.1f} mm of the block's walls")
    to_board = pose_matrix(rig['pose']) @ local
    ob.matrix_world = Matrix((FLIP @ to_board).tolist())
    rig['specimen_extent_mm'] = (inside.max(axis=0) - inside.min(axis=0)).round(2).tolist()
    rig['specimen_wall_gap_mm'] = round(float(gap), 2)
    # Radii scale as the joints do (fit's scale, times the specimen's length).
    rig['limbs'] = [{'name': name, 'joints_mm': (j @ to_board[:3, :3].T + to_board[:3, 3]).round(4).tolist(),
                     'radii_mm': (radii * length * np.linalg.norm(j[1] - j[0]) / np.linalg.norm(raw[1] - raw[0]))
                     .round(4).tolist()} for (name, raw, radii), j in zip(limbs, joints)]
    # A half turn about x keeps the winding: the triangles stay outward.
    return V @ to_board[:3, :3].T + to_board[:3, 3], F


def make_container(rig: dict) -> list:
    """blender_set's glass block (Blender's cube) at the rig's size, IOR and place, or its jar:
    a glass cylinder with a cylinder of liquid inside (IOR liquid / glass: Cycles takes each
    surface's IOR relative to the side its normal leaves)."""
    W, D, H = rig['size_mm']
    if rig['container'] == 'jar':
        wall = rig['wall_mm']
        obs = [bs.make_cylinder(0.5 * W, 0.5 * H, 'jar_glass', rig['ior'])[0],
               bs.make_cylinder(0.5 * W - wall, 0.5 * H - wall, 'jar_liquid', rig['liquid_ior'] / rig['ior'])[0]]
    else:
        ob, _ = bs.make_block((0.5 * W, 0.5 * D, 0.5 * H), -rig['pose'][2])   # yaw flips with y
        for node in ob.data.materials[0].node_tree.nodes:
            if node.bl_idname == 'ShaderNodeBsdfGlass':
                node.inputs['IOR'].default_value = rig['ior']
        if rig['edge_mm']:
            round_edges(ob, rig['edge_mm'])
        if rig['bow_mm']:
            bow_faces(ob, (0.5 * W, 0.5 * D, 0.5 * H), -rig['pose'][2], rig['bow_mm'])
        obs = [ob]
    for ob in obs:
        ob.location = (rig['pose'][0], -rig['pose'][1], 0.5 * H)
    return obs


def round_edges(ob, radius: float) -> None:
    """A polished block: its edges and corners rounded to ``radius`` (EDGE_SEGMENTS facets a
    quarter circle, shaded smooth), its faces flat to the rounding (hardened normals)."""
    for p in ob.data.polygons:
        p.use_smooth = True
    mod = ob.modifiers.new('round', 'BEVEL')
    mod.width, mod.segments, mod.limit_method, mod.harden_normals = radius, EDGE_SEGMENTS, 'NONE', True
    bpy.context.view_layer.objects.active = ob
    bpy.ops.object.modifier_apply(modifier='round')


def _bulge_module():
    """The project's bulge (``reneus_mi/geometry/bulge.py``: NumPy only), read from its file:
    importing the package would need Mitsuba, which Blender's Python lacks."""
    import importlib.util
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'reneus_mi', 'geometry', 'bulge.py')
    spec = importlib.util.spec_from_file_location('bulge', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def bow_faces(ob, half, yaw: float, bow: float) -> None:
    """A block polished convex: its four sides and its top bulge out by ``bow`` mm at their
    centres, 0 at their edges (``reneus_mi/geometry/bulge.py``); the bottom, which stands on the
    board, stays flat. ``ob`` is the block centred on its origin, turned by ``yaw``
    degrees about z."""
    bm = bmesh.new()
    bm.from_mesh(ob.data)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=BOW_CUTS, use_grid_fill=True)
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    p = np.array([v.co[:] for v in bm.verts])
    q = np.stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1], p[:, 2]], axis=1) / half
    # Each point on the face its largest coordinate puts it on (on an edge the bulge is 0).
    axis = np.argmax(np.abs(q), axis=1)
    n = np.zeros_like(q)
    n[np.arange(len(q)), axis] = np.sign(q[np.arange(len(q)), axis])
    # The faces -x +x -y +y -z +z; Blender's z is up: the bottom is the -z face.
    out = _bulge_module().displacement(q.T, n.T, [bow] * 4 + [0.0, bow], np.ones(3))
    for v, (dx, dy, dz) in zip(bm.verts, out):
        v.co.x += c * dx - s * dy
        v.co.y += s * dx + c * dy
        v.co.z += dz
    bm.to_mesh(ob.data)
    bm.free()


def make_camera(sc, K_r: np.ndarray, size: tuple[int, int]) -> bpy.types.Object:
    """A perspective camera equal to the pinhole frame K_r (size pixels) (:func:`frame_camera`)."""
    data = bpy.data.cameras.new('camera')
    data.sensor_fit, data.sensor_width = 'HORIZONTAL', 36.0
    data.clip_start, data.clip_end = 1.0, 1.0e4
    cam = bpy.data.objects.new('camera', data)
    sc.collection.objects.link(cam)
    sc.camera = cam
    frame_camera(sc, cam, K_r, size)
    return cam


def frame_camera(sc, cam, K_r: np.ndarray, size: tuple[int, int]) -> None:
    """Make the camera the pinhole K_r of ``size`` pixels: horizontal sensor fit, the principal
    point by lens shift (in units of the width)."""
    w, h = size
    sc.render.resolution_x, sc.render.resolution_y = w, h
    sc.render.pixel_aspect_x = sc.render.pixel_aspect_y = 1.0
    data = cam.data
    data.lens = K_r[0, 0] * data.sensor_width / w
    # A positive shift moves the frame right / up: the axis appears left of / below the centre.
    data.shift_x = (0.5 * w - K_r[0, 2]) / w
    data.shift_y = (K_r[1, 2] - 0.5 * h) / w


def place_camera(cam, c2w: np.ndarray) -> None:
    """Blender's camera (looking down its -z, y up) at an OpenCV camera-to-board c2w."""
    cam.matrix_world = Matrix((FLIP @ c2w @ FLIP).tolist())
    bpy.context.view_layer.update()


def check_camera(sc, cam, K_r: np.ndarray, c2w: np.ndarray, points: np.ndarray) -> float:
    """Largest distance (pixels) between Blender's projection of board points and K_r's."""
    place_camera(cam, c2w)
    w, h = sc.render.resolution_x, sc.render.resolution_y
    w2c = np.linalg.inv(c2w)
    cam_pts = points @ w2c[:3, :3].T + w2c[:3, 3]
    ours = cam_pts[:, :2] / cam_pts[:, 2:] @ np.diag([K_r[0, 0], K_r[1, 1]]) + K_r[:2, 2]
    theirs = []
    for p in points:
        q = world_to_camera_view(sc, cam, Vector(FLIP[:3, :3] @ p))
        theirs.append((q.x * w, (1.0 - q.y) * h))                # from the bottom-left corner
    return float(np.abs(ours - np.array(theirs)).max())


#: --board-factor: margin of the block's region rendered at full size, as a share of its
#: projection's larger side (and at least REGION_MARGIN_PX pixels).
REGION_MARGIN, REGION_MARGIN_PX = 0.08, 16


def block_region(c2w: np.ndarray, K_r: np.ndarray, frame: tuple[int, int], corners: np.ndarray):
    """x0, y0, x1, y1: the block's projection (its ``corners``, board frame) in the pinhole
    frame, with a margin, within the frame."""
    w2c = np.linalg.inv(c2w)
    cam = corners @ w2c[:3, :3].T + w2c[:3, 3]
    px = cam[:, :2] / cam[:, 2:] @ np.diag([K_r[0, 0], K_r[1, 1]]) + K_r[:2, 2]
    lo, hi = px.min(axis=0), px.max(axis=0)
    margin = max(REGION_MARGIN * (hi - lo).max(), REGION_MARGIN_PX)
    x0, y0 = np.maximum(np.floor(lo - margin), 0).astype(int)
    x1, y1 = np.minimum(np.ceil(hi + margin), frame).astype(int)
    return int(x0), int(y0), int(x1), int(y1)


def render_view(sc, cam, rig: dict, K_r: np.ndarray, frame: tuple[int, int], c2w: np.ndarray,
                folder: str, seed: int) -> np.ndarray:
    """One view's pinhole frame, linear: rendered whole, or (``board_factor`` K > 1) at 1/K and
    scaled up, with the block's region rendered at full size over it."""
    k = rig['board_factor']
    place_camera(cam, c2w)
    if k == 1:
        return render_linear(sc, folder, seed)
    frame_camera(sc, cam, np.diag([1.0 / k, 1.0 / k, 1.0]) @ K_r, (frame[0] // k, frame[1] // k))
    # cv2.resize by an integer factor keeps the pinhole: pixel centre u maps to u * k.
    linear = np.clip(cv2.resize(render_linear(sc, folder, seed), frame, interpolation=cv2.INTER_CUBIC), 0.0, None)
    x0, y0, x1, y1 = block_region(c2w, K_r, frame, rig['block_corners'])
    K_region = np.array(K_r, np.float64)
    K_region[:2, 2] -= (x0, y0)
    frame_camera(sc, cam, K_region, (x1 - x0, y1 - y0))
    linear[y0:y1, x0:x1] = render_linear(sc, folder, seed + 7919)
    frame_camera(sc, cam, K_r, frame)
    return linear


def render_linear(sc, folder: str, seed: int) -> np.ndarray:
    """One view through Cycles as (H,W,3) float32 linear radiance, top row first."""
    sc.cycles.seed = seed
    path = os.path.join(folder, 'view.exr')
    sc.render.filepath = path
    with bs.quiet():
        bpy.ops.render.render(write_still=True)
    pixels = bs.read_float_pixels(path)[:, :, :3].copy()
    os.remove(path)
    return pixels


# --- the capture ----------------------------------------------------------------------------

def _empty_dir(path: str, what: str) -> str:
    path = os.path.abspath(path)
    if os.path.exists(path) and (not os.path.isdir(path) or os.listdir(path)):
        sys.exit(f'error: {path}: {what} exists and is not an empty folder; choose a new one')
    os.makedirs(path, exist_ok=True)
    return path


def make_rig(args) -> dict:
    """Everything the capture is made of, drawn from ``args.seed`` where random."""
    block = BLOCKS[args.block]
    width, height = (int(v) for v in args.size.lower().split('x'))
    rng = np.random.default_rng(args.seed)
    cols, rows = block['squares']
    board_w, board_h = cols * block['square_mm'], rows * block['square_mm']
    pose = (board_w * (0.5 + rng.uniform(-POSE_JITTER, POSE_JITTER)),
            board_h * (0.5 + rng.uniform(-POSE_JITTER, POSE_JITTER)), rng.uniform(*YAW_RANGE))
    K = intrinsics(width, height)
    jar = dict(size_mm=JARS[args.block], wall_mm=JAR_WALL_MM, liquid_ior=LIQUID_IOR) if args.container == 'jar' else {}
    return dict(block=args.block, **{**block, **jar}, dictionary=DICTIONARY, paper_margin_mm=PAPER_MARGIN_MM,
                container=args.container, ior=args.ior, edge_mm=args.edge_mm, bow_mm=args.bow_mm, pose=[round(float(v), 3) for v in pose],
                specimen=args.specimen, width=width, height=height, K=K, distortion=list(DISTORTION),
                views=args.views, distance_mm=float(K[0, 0] * max(board_w, board_h) / (BOARD_SPAN * width)),
                board_factor=args.board_factor,
                spp=args.spp, adaptive_threshold=ADAPTIVE_THRESHOLD, seed=args.seed, rng=rng)


def capture_settings(rig: dict) -> dict:
    """capture.json as reneus_mi.capture.settings.to_json writes it."""
    x = lambda values: 'x'.join(f'{v:g}' for v in values)  # noqa: E731
    # A jar's rims are sharp here, as Blender's cylinder is: the photographer says so.
    jar = ({'wall_mm': rig['wall_mm'], 'liquid_ior': rig['liquid_ior'], 'edge_mm': 0.0}
           if rig['container'] == 'jar' else {})
    return {'board': 'charuco', 'squares': x(rig['squares']), 'square_mm': rig['square_mm'],
            'marker_mm': rig['marker_mm'], 'dictionary': rig['dictionary'], 'container': SHAPES[rig['container']],
            'size_mm': x(rig['size_mm']), 'ior': rig['ior'], **jar}


def capture(rig: dict, photos: str, truth: str, preview: bool) -> dict:
    """Render the capture ``rig`` into ``photos`` (JPEGs, capture.json) and ``truth``."""
    photos = _empty_dir(photos, 'photographs folder')
    truth = _empty_dir(truth, 'ground-truth folder')
    rng = rig.pop('rng')
    c2w = cameras(rig, rng)
    chosen = (np.unique(np.round(np.linspace(0, len(c2w) - 1, PREVIEW_VIEWS)).astype(int))
              if preview else np.arange(len(c2w)))
    gains = EXPOSURE * (1.0 + rng.uniform(-EXPOSURE_JITTER, EXPOSURE_JITTER, len(c2w)))
    K, dist, width, height = rig['K'], rig['distortion'], rig['width'], rig['height']

    start = time.perf_counter()
    sc = setup_cycles(rig['spp'])
    make_board(rig)
    make_container(rig)
    V, F = make_specimen(rig)
    bs.write_ply(os.path.join(truth, 'specimen.ply'), V, F)
    Vc, Fc = container_mesh(SHAPES[rig['container']], rig['size_mm'], rig['pose'])
    bs.write_ply(os.path.join(truth, 'container.ply'), Vc, Fc)
    K_r, frame = pinhole_frame(K, dist, width, height)
    k = rig['board_factor']
    frame = (k * math.ceil(frame[0] / k), k * math.ceil(frame[1] / k))
    rig['block_corners'] = Vc
    cam = make_camera(sc, K_r, frame)
    maps = distortion_maps(K, dist, K_r, width, height)
    cols, rows = rig['squares']
    board_pts = np.array([[x, y, 0.0] for x in (0.0, cols * rig['square_mm']) for y in (0.0, rows * rig['square_mm'])])
    camera_error = max(check_camera(sc, cam, K_r, c, board_pts) for c in c2w)
    if k > 1:      # the region's camera, as render_view frames it, on the block's corners
        x0, y0, x1, y1 = block_region(c2w[0], K_r, frame, Vc)
        K_region = np.array(K_r, np.float64)
        K_region[:2, 2] -= (x0, y0)
        frame_camera(sc, cam, K_region, (x1 - x0, y1 - y0))
        camera_error = max(camera_error, check_camera(sc, cam, K_region, c2w[0], Vc))
        frame_camera(sc, cam, K_r, frame)
    if camera_error > 1e-3 * max(1.0, width / SIZE[0]):     # Blender's float32 lens, larger frames
        sys.exit(f"error: Blender's camera projects the board's corners {camera_error:.4f} px from K_r")
    setup_seconds = time.perf_counter() - start
    print(f"{rig['specimen']} in the {rig['block']} {rig['container']} ({len(V)} vertices), {len(chosen)} views of "
          f"{width}x{height} (pinhole frame {frame[0]}x{frame[1]}), {rig['spp']} spp; set up in "
          f"{setup_seconds:.0f} s", flush=True)

    views, seconds = [], []
    with tempfile.TemporaryDirectory(prefix='.render_', dir=truth) as scratch:
        for n, i in enumerate(chosen):
            t0 = time.perf_counter()
            linear = render_view(sc, cam, rig, K_r, frame, c2w[i], scratch, seed=rig['seed'] * 1000 + int(i))
            seconds.append(time.perf_counter() - t0)
            photo = cv2.remap(linear, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            photo = expose(photo, float(gains[i]), rng)
            name = f'IMG_{i + 1:04d}.jpg'
            ok, data = cv2.imencode('.jpg', photo[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            bs._atomic_bytes(os.path.join(photos, name), data.tobytes())
            views.append({'name': name, 'c2w': c2w[i].tolist(), 'gain': float(gains[i])})
            print(f'\r{n + 1}/{len(chosen)} views, {seconds[-1]:.1f} s the last, '
                  f'{time.perf_counter() - start:.0f} s in all', end='', flush=True)
    print()
    bs.write_json(os.path.join(photos, 'capture.json'), capture_settings(rig))
    W, D, H = rig['size_mm']
    limbs = rig.pop('limbs')
    rig.pop('block_corners')
    result = {'rig': {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in rig.items()},
              'K': K.tolist(), 'distortion': list(dist), 'width': width, 'height': height, 'views': views,
              'container': {'shape': SHAPES[rig['container']], 'size_mm': [W, D, H], 'pose': list(rig['pose']),
                            'mesh': 'container.ply',
                            **{k: rig[k] for k in ('wall_mm', 'liquid_ior') if k in rig}},
              'specimen': 'specimen.ply', 'limbs': limbs, 'ambient': AMBIENT,
              'board': {'white': PAPER_WHITE * AMBIENT, 'black': INK_BLACK * AMBIENT, 'contact_gap_mm': CONTACT_GAP},
              'frame': 'board (OpenCV ChArUco), millimetres',
              'renderer': 'blender cycles', 'blender': bpy.app.version_string,
              'render': {'threads': THREADS, 'spp': rig['spp'], 'adaptive_threshold': ADAPTIVE_THRESHOLD,
                         'denoiser': sc.cycles.denoiser, 'denoising_quality': DENOISING_QUALITY,
                         'denoising_prefilter': sc.cycles.denoising_prefilter, 'pinhole_frame': list(frame), 'K_pinhole': K_r.tolist(),
                         'board_factor': k,
                         'setup_seconds': setup_seconds, 'seconds_per_view': float(np.mean(seconds)),
                         'seconds': [round(s, 2) for s in seconds], 'wall_seconds': time.perf_counter() - start,
                         'camera_check_px': camera_error}}
    bs.write_json(os.path.join(truth, 'truth.json'), result)
    return result


# --- --check: the photographs' corners against the truth ------------------------------------

def block_outline(c2w: np.ndarray, K_cv: np.ndarray, dist, shape: str, size_mm, pose) -> np.ndarray:
    """The container's outline in a photograph (OpenCV pixels): the convex hull of its
    vertices' projections, lens included."""
    w2c = np.linalg.inv(c2w)
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    corners, _ = cv2.projectPoints(container_mesh(shape, size_mm, pose)[0], rvec, w2c[:3, 3], K_cv, dist)
    return cv2.convexHull(corners.reshape(-1, 2).astype(np.float32))


def detect_corners(gray: np.ndarray, board, aruco, square_over_marker: float):
    """ChArUco corner ids and positions (reneus-mi convention), refined to the saddles as
    reneus_mi.capture.charuco does (cornerSubPix, a window of 0.15 square)."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    marker_corners, marker_ids, _ = cv2.aruco.ArucoDetector(aruco, params).detectMarkers(gray)
    if marker_ids is None or len(marker_ids) < 2:
        return np.zeros(0, int), np.zeros((0, 2)), 0
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(
        gray, markerCorners=marker_corners, markerIds=marker_ids)
    if ids is None or not len(ids):
        return np.zeros(0, int), np.zeros((0, 2)), 0
    m = np.asarray(marker_corners, np.float64).reshape(-1, 4, 2)
    side = np.median(np.linalg.norm(np.diff(m, axis=1, append=m[:, :1]), axis=-1))
    half = int(max(2, round(0.15 * side * square_over_marker)))
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    refined = cv2.cornerSubPix(gray, np.asarray(corners, np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), criteria)
    return np.asarray(ids).ravel(), refined.reshape(-1, 2).astype(np.float64) + 0.5, half


def check(photos: str, truth: str) -> dict:
    """Reprojection error of the corners seen through the air: detected in each JPEG against
    the truth's projection of the print's corners (at z = CONTACT_GAP, where they are),
    leaving out those whose refinement window reaches the block's outline.

    Corners of very oblique views (the low ring in portrait) can be 1-2 px off: the window of
    0.15 square, sized by the median marker, spans neighbouring edges where the squares are
    foreshortened; measured on view 3 of the ant capture, a 3 px window gives at most 0.24
    px, and a render without denoising (128 spp) the same errors as the denoised one."""
    with open(os.path.join(truth, 'truth.json')) as f:
        meta = json.load(f)
    rig = meta['rig']
    aruco = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, rig['dictionary']))
    board = cv2.aruco.CharucoBoard(tuple(rig['squares']), rig['square_mm'], rig['marker_mm'], aruco)
    board.setLegacyPattern(False)
    points = np.asarray(board.getChessboardCorners(), np.float64).reshape(-1, 3)
    points[:, 2] = meta['board'].get('contact_gap_mm', CONTACT_GAP)
    K_cv, dist = _opencv_K(np.array(meta['K'])), np.array(meta['distortion'])
    block = meta['container']['shape'], meta['container']['size_mm'], meta['container']['pose']
    per_view, errors = [], []
    for view in meta['views']:
        gray = cv2.imread(os.path.join(photos, view['name']), cv2.IMREAD_GRAYSCALE)
        ids, pixels, half = detect_corners(gray, board, aruco, rig['square_mm'] / rig['marker_mm'])
        c2w = np.array(view['c2w'])
        w2c = np.linalg.inv(c2w)
        rvec, _ = cv2.Rodrigues(w2c[:3, :3])
        proj, _ = cv2.projectPoints(points[ids], rvec, w2c[:3, 3], K_cv, dist)
        offset = proj.reshape(-1, 2) + 0.5 - pixels
        outline = block_outline(c2w, K_cv, dist, *block)
        # Signed distance to the outline, positive inside; the window is a square of 2 half + 1.
        inside = np.array([cv2.pointPolygonTest(outline, (float(x - 0.5), float(y - 0.5)), True)
                           for x, y in pixels]).reshape(-1)
        air = inside < -(math.sqrt(2.0) * (half + 1) + CHECK_MARGIN_PX)
        e = np.linalg.norm(offset, axis=1)
        errors.append(e[air])
        per_view.append({'name': view['name'], 'corners': int(len(ids)), 'in_air': int(air.sum()),
                         'median_px': float(np.median(e[air])) if air.any() else None,
                         'max_px': float(e[air].max()) if air.any() else None,
                         'mean_offset_px': offset[air].mean(axis=0).round(3).tolist() if air.any() else None,
                         'near_block_max_px': float(e[~air].max()) if (~air).any() else None})
    e = np.concatenate(errors)
    return {'views': per_view, 'corners': int(len(e)), 'median_px': float(np.median(e)),
            'p95_px': float(np.percentile(e, 95)), 'max_px': float(e.max())}


def report_check(photos: str, truth: str) -> dict:
    result = check(photos, truth)
    for v in result['views']:
        near = '' if v['near_block_max_px'] is None else f", near the block up to {v['near_block_max_px']:.2f} px"
        print(f"{v['name']}: {v['corners']} corners, {v['in_air']} through the air: median "
              f"{v['median_px']:.3f} px, max {v['max_px']:.3f} px, mean offset {v['mean_offset_px']}{near}")
    print(f"corners through the air: {result['corners']}, median {result['median_px']:.3f} px, "
          f"95th percentile {result['p95_px']:.3f} px, max {result['max_px']:.3f} px")
    return result


def reduce_capture(src_photos: str, src_truth: str, photos: str, truth: str, size: tuple[int, int]) -> None:
    """The capture ``src_*`` as a camera of ``size`` pixels (the same lens and cameras) would
    have taken it: each photograph decoded, area-averaged and written as a JPEG again (its
    noise averaged too: milder than a small sensor's), the truth's K scaled."""
    photos, truth = _empty_dir(photos, 'photographs folder'), _empty_dir(truth, 'ground-truth folder')
    with open(os.path.join(src_truth, 'truth.json')) as f:
        meta = json.load(f)
    scale = np.array([size[0] / meta['width'], size[1] / meta['height']])
    if abs(scale[0] - scale[1]) > 1e-3:
        sys.exit(f"error: {size[0]}x{size[1]} is not the shape of {meta['width']}x{meta['height']}")
    for view in meta['views']:
        image = cv2.imread(os.path.join(src_photos, view['name']))
        small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        ok, data = cv2.imencode('.jpg', small, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        bs._atomic_bytes(os.path.join(photos, view['name']), data.tobytes())
    for name in ('capture.json',):
        with open(os.path.join(src_photos, name), 'rb') as f:
            bs._atomic_bytes(os.path.join(photos, name), f.read())
    for name in ('specimen.ply', 'container.ply'):
        with open(os.path.join(src_truth, name), 'rb') as f:
            bs._atomic_bytes(os.path.join(truth, name), f.read())
    meta['K'] = (np.diag([scale[0], scale[1], 1.0]) @ np.array(meta['K'])).tolist()
    meta['width'], meta['height'] = size
    meta['reduced_from'] = {'photos': os.path.abspath(src_photos), 'truth': os.path.abspath(src_truth)}
    bs.write_json(os.path.join(truth, 'truth.json'), meta)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(
        prog='bench/blender_capture.py',
        description='Render a museum-style capture (a specimen in a glass block on a ChArUco board) '
                    "with Blender Cycles, as reneus_mi.capture.simulation does with Mitsuba (run with the bpy venv's Python).")
    parser.add_argument('photos', metavar='PHOTOS', help='folder for the photographs and capture.json (new or empty)')
    parser.add_argument('--truth', required=True, help='folder for the ground truth (new or empty)')
    parser.add_argument('--specimen', choices=list(SPECIMENS), default='ant')
    parser.add_argument('--block', choices=list(BLOCKS), default='small',
                        help='small: 40x30x22 mm on a 10x7 board of 24 mm; large: 60x45x30 mm on 12x9 of 25 mm')
    parser.add_argument('--container', choices=list(SHAPES), default='box',
                        help='box: a solid glass block; jar: a glass jar of ethanol on the same board '
                             f'({JARS["small"][0]:g} x {JARS["small"][2]:g} mm, walls {JAR_WALL_MM:g} mm)')
    parser.add_argument('--size', default='x'.join(map(str, SIZE)), help='photograph size WxH (default: %(default)s)')
    parser.add_argument('--board-factor', type=int, default=1, metavar='K',
                        help='render the frame at 1/K of --size, scaled up, and only the block\'s region at '
                             'full size (12 MP and more in reasonable time; default: %(default)s, all at full size)')
    parser.add_argument('--views', type=int, default=48)
    parser.add_argument('--spp', type=int, default=SPP, help='Cycles samples per pixel, at most (adaptive)')
    parser.add_argument('--ior', type=float, default=IOR)
    parser.add_argument('--edge-mm', type=float, default=0.0, metavar='R',
                        help="the block's edges and corners rounded to radius R mm (polished), while capture.json "
                             'states a sharp box, as a curator who has not measured them would (default: sharp)')
    parser.add_argument('--bow-mm', type=float, default=0.0, metavar='S',
                        help="the block's sides and top bulging out by S mm at their centres (polished convex), "
                             'while capture.json states a flat-faced box (default: flat)')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--preview', action='store_true', help=f'render only {PREVIEW_VIEWS} of the views')
    parser.add_argument('--check', action='store_true',
                        help='only compare the corners of existing PHOTOS with the TRUTH of them')
    parser.add_argument('--reduce-from', nargs=2, metavar=('SRC_PHOTOS', 'SRC_TRUTH'),
                        help='only write an existing capture reduced to --size (area averaging) into PHOTOS, TRUTH')
    parser.add_argument('--limbs', action='store_true',
                        help="only write the legs' and antennae's axes into an existing TRUTH (as the same "
                             'arguments make them), for a capture rendered before truth.json had them')
    args = parser.parse_args(argv)
    if args.bow_mm and (args.edge_mm or args.container != 'box'):
        parser.error('--bow-mm bows a sharp box: not with --edge-mm or --container jar')
    cv2.setNumThreads(THREADS)
    if args.reduce_from:
        reduce_capture(*args.reduce_from, args.photos, args.truth, tuple(int(v) for v in args.size.lower().split('x')))
        return
    if args.limbs:
        rig = make_rig(args)
        setup_cycles(rig['spp'])
        make_specimen(rig)
        path = os.path.join(args.truth, 'truth.json')
        with open(path) as f:
            meta = json.load(f)
        meta['limbs'] = rig['limbs']
        bs.write_json(path, meta)
        print(f"{len(rig['limbs'])} limbs written to {path}")
        return
    if not args.check:
        rig = make_rig(args)
        result = capture(rig, args.photos, args.truth, args.preview)
        print(f"wrote {len(result['views'])} photographs to {args.photos}, the truth to {args.truth}; "
              f"{result['render']['seconds_per_view']:.1f} s a view, {result['render']['wall_seconds']:.0f} s in all")
    figures = report_check(args.photos, args.truth)
    if not args.check:
        path = os.path.join(args.truth, 'truth.json')
        with open(path) as f:
            meta = json.load(f)
        meta['corner_check'] = {k: v for k, v in figures.items() if k != 'views'}
        bs.write_json(path, meta)


if __name__ == '__main__':
    main()
