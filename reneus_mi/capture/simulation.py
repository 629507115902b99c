"""A photographer's capture, rendered: the test bed of :mod:`reneus_mi.capture`.

Mitsuba's ``path`` integrator renders the paper's real set-up (Sec. 4, "Real Dataset"): a
specimen inside a glass container standing on a printed ChArUco board (OpenCV's pattern as a
diffuse texture on a sheet of paper with a white margin), in a light tent (a constant
environment), photographed from a hemisphere (rings of elevations, turntable azimuths; each
view aimed roughly, with a little roll). Each photograph then goes through what a camera
does: a lens distortion (k1, k2, p1, p2, k3) and an off-centre principal point, an exposure
that drifts between shots, sensor noise (shot and read), the display curve and JPEG.

Written for the photographer (``PHOTOS``): only the JPEGs and ``capture.json`` (the board
and the container as measured). Written apart (``TRUTH``): ``truth.json`` (intrinsics,
distortion, every camera in the board's frame, exposure gains, the container's place, the
light), ``container.ply`` (and a hollow one's ``container_inner.ply``) and ``specimen.ply`` in
the board's frame, millimetres.

The command (:mod:`reneus_mi.simulate`)::

    python -m reneus_mi.simulate PHOTOS --truth TRUTH [--specimen insect] [--views 16]
"""
from __future__ import annotations

import dataclasses
import json
import os

import cv2
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.capture.charuco import Board
from reneus_mi.capture.placement import interfaces, local_mesh, pose_matrix
from reneus_mi.capture.settings import CAPTURE_FILE, CaptureSettings, to_json
from reneus_mi.data.cameras import look_at
from reneus_mi.data.dataset import CONTACT_GAP
from reneus_mi.data.objects import load_object
from reneus_mi.data.scene_xml import sensor_dict
from reneus_mi.data.synthetic import write_object
from reneus_mi.geometry.bulge import displacement
from reneus_mi.geometry.container import shading_mesh
from reneus_mi.geometry.shapes import write_container
from reneus_mi.geometry.mesh import mitsuba_mesh
from reneus_mi.paper import GAMMA
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_path, atomic_write_text

#: Halvings of a bowed block's triangles (:func:`bowed_block`): a face in 32 x 32 pairs of facets.
BOW_SUBDIVISIONS = 5


@dataclasses.dataclass
class Rig:
    """The capture to simulate: board, container, specimen, camera, light and photographs."""
    squares: tuple[int, int] = (12, 9)
    square_mm: float = 20.0
    marker_mm: float = 15.0
    dictionary: str = 'DICT_4X4_100'
    paper_margin_mm: float = 15.0
    """White paper around the printed pattern."""
    container: str = 'box'
    size_mm: tuple[float, float, float] = (50.0, 35.0, 25.0)
    ior: float = 1.5
    wall_mm: float | None = None
    """A hollow container's walls (a case, a jar); None: a solid block."""
    liquid_ior: float | None = None
    """The liquid in a hollow container; None: air."""
    edge_mm: float | None = None
    """A rounded block's edge radius; None: the generator's (a share of the smallest size)."""
    bow_mm: float = 0.0
    """A sharp block's four sides and top bulging out by this much at their centres, the bottom
    on the board flat (:mod:`reneus_mi.geometry.bulge`): a polished block's faces. The
    photographer states a box."""
    pose: tuple[float, float, float] = (117.3, 93.6, 23.0)
    """Where the container stands: footprint centre x, y (mm) and yaw (degrees)."""
    specimen: str = 'insect'
    specimen_fill: float = 0.6
    """Largest share of the container's inner size the specimen takes along each axis."""
    width: int = 640
    height: int = 480
    focal_px: float = 700.0
    principal_offset_px: tuple[float, float] = (9.3, -6.1)
    """Principal point minus the image centre."""
    distortion: tuple[float, ...] = (-0.12, 0.06, 0.0008, -0.0005, 0.0)
    """OpenCV's k1, k2, p1, p2, k3."""
    elevations: tuple[float, ...] = (35.0, 55.0, 75.0)
    views_per_ring: tuple[int, ...] = (6, 6, 4)
    distance_mm: float = 380.0
    aim_jitter_mm: float = 8.0
    roll_jitter_deg: float = 3.0
    portrait_every: int = 3
    """Every this many shots the camera is turned to portrait (rolled 90 degrees, alternately
    left and right): tilts about both image axes pin the principal point down (0: never)."""
    ambient: float = 1.0
    """Radiance of the light tent (linear)."""
    paper_white: float = 0.8
    ink_black: float = 0.04
    exposure: float = 0.6
    """Camera gain: linear radiance x exposure is the sensor value before the display curve."""
    exposure_jitter: float = 0.15
    """Each shot's gain is exposure x (1 + U(-j, j))."""
    read_noise: float = 0.002
    shot_noise: float = 0.0004
    """Sensor noise variance: read^2 + shot x value (linear)."""
    jpeg_quality: int = 92
    spp: int = 32
    max_depth: int = 10
    texture_px_per_mm: float = 8.0
    seed: int = 0

    @property
    def board(self) -> Board:
        return Board(*self.squares, self.square_mm, self.marker_mm, self.dictionary)

    def settings(self) -> CaptureSettings:
        """What the photographer writes down: the board, the container, its IOR."""
        return CaptureSettings(squares=tuple(self.squares), square_mm=self.square_mm,
                               marker_mm=self.marker_mm, dictionary=self.dictionary,
                               container=self.container, size_mm=tuple(self.size_mm), ior=self.ior,
                               wall_mm=self.wall_mm, liquid_ior=self.liquid_ior, edge_mm=self.edge_mm)

    def K(self) -> np.ndarray:
        cx = 0.5 * self.width + self.principal_offset_px[0]
        cy = 0.5 * self.height + self.principal_offset_px[1]
        return np.array([[self.focal_px, 0.0, cx], [0.0, self.focal_px, cy], [0.0, 0.0, 1.0]])


def cameras(rig: Rig, rng: np.random.Generator) -> np.ndarray:
    """OpenCV camera-to-board matrices (N,4,4) on a hemisphere above the container."""
    centre = np.array([rig.pose[0], rig.pose[1], -0.5 * rig.size_mm[2]])
    c2ws = []
    for ring, (elevation, count) in enumerate(zip(rig.elevations, rig.views_per_ring)):
        start = rng.uniform(0.0, 360.0 / count)
        for k in range(count):
            azimuth = np.radians(start + 360.0 * k / count)
            e = np.radians(elevation + rng.uniform(-3.0, 3.0))
            d = rig.distance_mm * (1.0 + rng.uniform(-0.05, 0.05))
            # Up is -z: the board's z points into the table.
            eye = centre + d * np.array([np.cos(e) * np.cos(azimuth), np.cos(e) * np.sin(azimuth), -np.sin(e)])
            target = centre + rng.uniform(-rig.aim_jitter_mm, rig.aim_jitter_mm, 3) * [1, 1, 0.3]
            c2w = look_at(eye, target, up=(0.0, 0.0, -1.0))
            roll = rng.uniform(-rig.roll_jitter_deg, rig.roll_jitter_deg)
            n = len(c2ws)
            if rig.portrait_every and n % rig.portrait_every == rig.portrait_every - 1:
                roll += 90.0 if (n // rig.portrait_every) % 2 else -90.0
            roll = np.radians(roll)
            c, s = np.cos(roll), np.sin(roll)
            c2w[:3, :3] = c2w[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            c2ws.append(c2w)
    return np.stack(c2ws)


def board_shape(rig: Rig) -> mi.Mesh:
    """The printed sheet: the pattern with its white margin, a diffuse textured quad facing -z,
    ``CONTACT_GAP`` under the container as in the scenes that reconstruct it
    (:func:`reneus_mi.data.scene_xml.board_to_world`)."""
    board = rig.board
    ppm = rig.texture_px_per_mm
    pad = int(round(rig.paper_margin_mm * ppm))
    pattern = np.pad(board.pattern(ppm), pad, constant_values=255).astype(np.float32) / 255.0
    albedo = rig.ink_black + (rig.paper_white - rig.ink_black) * pattern
    w, h = board.size_mm
    m = pad / ppm
    # The pattern's pixel grid is exactly that of the board (see Board.pattern).
    lo, hi = -m, np.array([w + m, h + m])
    z = CONTACT_GAP
    v = np.array([[lo, lo, z], [hi[0], lo, z], [hi[0], hi[1], z], [lo, hi[1], z]], np.float32)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    props = mi.Properties()
    props['bsdf'] = mi.load_dict({'type': 'diffuse', 'reflectance': {
        'type': 'bitmap', 'bitmap': mi.Bitmap(albedo[..., None]), 'raw': True}})
    # Wound so that the face normal is -z, towards the cameras.
    return mitsuba_mesh(v, [[0, 2, 1], [0, 3, 2]], 'board', props, texcoords=uv)


def specimen_mesh(rig: Rig) -> trimesh.Trimesh:
    """The specimen (coloured) inside the container, in the board's frame."""
    mesh = load_object(rig.specimen)
    wall = rig.wall_mm or 0.0
    inner = local_mesh(rig.container, rig.size_mm, wall, rig.edge_mm)
    # A jar's or rounded block's inner box is smaller than its outer size.
    room = (np.asarray(rig.size_mm) - 2.0 * wall) * (0.7 if rig.container == 'cylinder' else 1.0)
    scale = rig.specimen_fill * np.min(room / mesh.extents)
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    mesh.apply_scale(scale)
    mesh.apply_translation([0.0, 0.0, inner.bounds.mean(axis=0)[2]])
    mesh.apply_transform(pose_matrix(rig.pose))
    return mesh


def bowed_block(mesh: trimesh.Trimesh, rig: Rig) -> trimesh.Trimesh:
    """The sharp block ``mesh`` (the board's frame) cut finer (:data:`BOW_SUBDIVISIONS`), its
    sides and top bulging out by ``rig.bow_mm``."""
    if rig.container != 'box' or rig.wall_mm is not None:
        raise ReneusError(f'bow_mm={rig.bow_mm:g}: expected a solid sharp block (container box, no '
                          f'wall_mm), not a {rig.container}' + (' with walls' if rig.wall_mm is not None else ''))
    for _ in range(BOW_SUBDIVISIONS):
        mesh = trimesh.Trimesh(*trimesh.remesh.subdivide(mesh.vertices, mesh.faces))
    M = pose_matrix(rig.pose)
    # The block's frame: centred, up is -z, so its top is the -z face and its bottom the +z.
    q = (mesh.vertices - M[:3, 3]) @ M[:3, :3] + [0.0, 0.0, 0.5 * rig.size_mm[2]]
    n = np.asarray(mesh.vertex_normals) @ M[:3, :3]
    move = displacement(q.T, n.T, [rig.bow_mm] * 5 + [0.0], 0.5 * np.asarray(rig.size_mm))
    return trimesh.Trimesh(mesh.vertices + move @ M[:3, :3].T, mesh.faces, process=False)


def render_pinhole_frame(scene: mi.Scene, rig: Rig, c2w: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear render of a pinhole camera whose frame covers the distorted photograph, and its K."""
    K, dist = rig.K(), np.asarray(rig.distortion, np.float64)
    w, h = rig.width, rig.height
    # Where the photograph's border looks, undistorted: the pinhole render must reach it.
    t = np.linspace(0.0, 1.0, 64)
    border = np.concatenate([np.c_[t * w, 0 * t], np.c_[t * w, h + 0 * t], np.c_[0 * t, t * h], np.c_[w + 0 * t, t * h]])
    normal = _undistort_points(border, K, dist)
    f = rig.focal_px
    lo = np.floor(normal.min(axis=0) * f) - 2
    hi = np.ceil(normal.max(axis=0) * f) + 2
    size = (hi - lo).astype(int)
    K_r = np.array([[f, 0.0, -lo[0]], [0.0, f, -lo[1]], [0.0, 0.0, 1.0]])
    sensor = mi.load_dict(sensor_dict(K_r, c2w, int(size[0]), int(size[1])))
    image = np.asarray(mi.render(scene, sensor=sensor, spp=rig.spp, seed=seed), np.float32)
    return image, K_r


def _undistort_points(pixels: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Normalised pinhole coordinates (x/z, y/z) of distorted pixels (reneus-mi convention)."""
    K_cv = K.copy()
    K_cv[:2, 2] -= 0.5
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    out = cv2.undistortPointsIter(np.ascontiguousarray(pixels - 0.5, np.float64).reshape(-1, 1, 2),
                                  K_cv, dist, None, None, criteria)
    return out.reshape(-1, 2)


def distort_image(pinhole: np.ndarray, K_r: np.ndarray, rig: Rig) -> np.ndarray:
    """The photograph the lens makes of a pinhole render (bilinear resampling)."""
    K, dist = rig.K(), np.asarray(rig.distortion, np.float64)
    ys, xs = np.mgrid[:rig.height, :rig.width]
    pixels = np.stack([xs.ravel(), ys.ravel()], axis=1) + 0.5
    normal = _undistort_points(pixels.astype(np.float64), K, dist)
    src = normal * [K_r[0, 0], K_r[1, 1]] + K_r[:2, 2] - 0.5
    maps = src.reshape(rig.height, rig.width, 2).astype(np.float32)
    return cv2.remap(pinhole, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def expose(linear: np.ndarray, gain: float, rig: Rig, rng: np.random.Generator) -> np.ndarray:
    """8-bit RGB of a linear image: gain, sensor noise, the display curve."""
    value = linear * gain
    value = value + rng.normal(size=value.shape) * np.sqrt(rig.read_noise ** 2 + rig.shot_noise * np.clip(value, 0, None))
    display = np.clip(value, 0.0, 1.0) ** (1.0 / GAMMA)
    return np.round(display * 255.0).astype(np.uint8)


def simulate(rig: Rig, photos: str, truth: str) -> dict:
    """Render the capture ``rig`` into ``photos`` (JPEGs, capture.json) and ``truth``."""
    rig.board.check()
    rig.settings().check('simulated capture')
    photos = guards.check_output_dir(photos, what='photographs folder')
    truth = guards.check_output_dir(truth, inputs=[photos], what='ground-truth folder')
    rng = np.random.default_rng(rig.seed)
    c2w = cameras(rig, rng)
    os.makedirs(truth, exist_ok=True)
    # Shaded with the normals the reneus integrator gives the same files.
    shapes, outside = {}, 1.0
    for interface, mesh in interfaces(rig.container, rig.size_mm, rig.ior, rig.wall_mm, rig.liquid_ior, rig.pose,
                                      rig.edge_mm):
        if rig.bow_mm:
            mesh = bowed_block(mesh, rig)
        path = os.path.join(truth, interface.mesh)
        write_container(mesh, path, normals=rig.container != 'box')
        shapes[os.path.splitext(interface.mesh)[0]] = shading_mesh(path, bsdf={
            'type': 'dielectric', 'int_ior': interface.ior, 'ext_ior': outside})
        outside = interface.ior
    specimen = specimen_mesh(rig)
    specimen_path = os.path.join(truth, 'specimen.ply')
    write_object(specimen, specimen_path)
    scene = mi.load_dict({
        'type': 'scene',
        'integrator': {'type': 'path', 'max_depth': rig.max_depth, 'rr_depth': rig.max_depth},
        'tent': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': [rig.ambient] * 3}},
        'board': board_shape(rig),
        **shapes,
        'specimen': {'type': 'ply', 'filename': specimen_path,
                     'bsdf': {'type': 'diffuse', 'reflectance': {'type': 'mesh_attribute', 'name': 'vertex_color'}}},
    })
    os.makedirs(photos, exist_ok=True)
    views, gains = [], []
    for i, cam in enumerate(c2w):
        pinhole, K_r = render_pinhole_frame(scene, rig, cam, seed=rig.seed * 1000 + i)
        gain = rig.exposure * (1.0 + rng.uniform(-rig.exposure_jitter, rig.exposure_jitter))
        photo = expose(distort_image(pinhole, K_r, rig), gain, rig, rng)
        name = f'IMG_{i + 1:04d}.jpg'
        ok, data = cv2.imencode('.jpg', photo[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, rig.jpeg_quality])
        with atomic_path(os.path.join(photos, name)) as tmp, open(tmp, 'wb') as f:
            f.write(data.tobytes())
        views.append({'name': name, 'c2w': cam.tolist(), 'gain': gain})
        gains.append(gain)
    atomic_write_text(os.path.join(photos, CAPTURE_FILE), json.dumps(to_json(rig.settings()), indent=2))
    result = {'rig': {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(rig).items()},
              'K': rig.K().tolist(), 'distortion': list(rig.distortion), 'width': rig.width,
              'height': rig.height, 'views': views, 'container': {
                  'shape': rig.container, 'size_mm': list(rig.size_mm), 'wall_mm': rig.wall_mm,
                  'liquid_ior': rig.liquid_ior, 'pose': list(rig.pose), 'mesh': 'container.ply',
                  **({'inner_mesh': 'container_inner.ply'} if rig.wall_mm is not None else {})},
              'specimen': 'specimen.ply', 'ambient': rig.ambient,
              'board': {'white': rig.paper_white * rig.ambient, 'black': rig.ink_black * rig.ambient},
              'frame': 'board (OpenCV ChArUco), millimetres'}
    atomic_write_text(os.path.join(truth, 'truth.json'), json.dumps(result, indent=2))
    return result
