"""What surrounds the field, and what the paper takes as known: the container's IOR
and pose, and the light (beyond the paper: Sec. 5 names them as its limitation).

The ``reneus`` integrator owns one :class:`Surroundings` per scene, built from
the scene when it first renders it: the IOR from the container's ``dielectric``
BSDF, the pose at identity (the container as the scene places it), the light
from the scene's environment emitter. Their values are Dr.Jit arrays that
``mi.traverse(scene)`` shows under the names of :meth:`Surroundings.params`
(``container.eta``, ``container.translation``, ``light.sh``, ...); the trainer
refines those a run asks for, like the field's own parameters.

Container pose: a world point x of the container as loaded goes to

    x' = R(r) diag(exp(σ)) (x - c) + c + τ

with ``τ`` the translation, ``r`` a rotation vector (axis x angle), ``σ`` the
per-axis log-scale and ``c`` the centre of the container's bounding box. Rays
are taken into the container's frame, intersected with the mesh as loaded and
their hit distance, point and normals mapped back differentiably: the
derivatives are the interior ones (how refraction moves with the glass).

Light: ``ambient`` is one RGB radiance for every direction (the paper's C_out);
``sh`` a real spherical-harmonics expansion up to order 2 (9 RGB
coefficients), for rooms that are not uniform.

Backdrop (beyond the paper): shapes of the scene with an ``area``
emitter, e.g. the printed board the container stands on. A ray that leaves the container
takes the radiance of the backdrop it meets, and C_out only where it meets none: rays
leaving a block through its bottom see the board, not the tent, and the paper's model
(Sec. 5 blames such violations for its drop on real data) paints the difference into the
field. The container and the backdrop are each a Mitsuba scene of their own, built from
the loaded scene's shapes: the container is intersected in its own frame (the refined pose
moves the rays, not the mesh) while the backdrop stays where the scene puts it, so one
scene cannot serve both. Mitsuba's own intersection and ``emitter.eval`` then give exactly
the radiance that its ``path`` integrator sees (the same uv, texture filter and
one-sidedness, on any shape), differentiable in the ray: the IOR and the pose move where a
refracted ray meets the printed pattern. An analytic plane with a texture lookup would
copy the rectangle's parametrisation and the bitmap's filtering, and allow planes only.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.geometry.container import CREASE_ANGLE, scene_of, shading_normals
from reneus_mi.render.interfaces import Interfaces, interfaces_of
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.param_groups import ParamGroup

#: Light models: the scene's emitter as given, one refinable RGB radiance, order-2 SH.
LIGHTS = ('emitter', 'ambient', 'sh')
#: Y_00, the constant spherical harmonic: an SH light's mean radiance is c_00 Y_00.
_Y00 = 0.282095
#: Directions that project an emitter onto the SH basis (Fibonacci sphere).
_PROJECTION_DIRECTIONS = 4096
#: Learning rate of the board's log-gains relative to the run's: 1e-2 at the fast preset's
#: 1e-3, a percent of light per step.
SHADING_LR_SCALE = 10.0


def sh_basis(d: mi.Vector3f) -> list:
    """The 9 real spherical harmonics Y_lm (l <= 2) of unit directions ``d``."""
    x, y, z = d.x, d.y, d.z
    return [_Y00 + 0.0 * x,
            0.488603 * y, 0.488603 * z, 0.488603 * x,
            1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3.0 * z * z - 1.0),
            1.092548 * x * z, 0.546274 * (x * x - y * y)]


def fibonacci_directions(n: int) -> np.ndarray:
    """``n`` nearly uniform unit vectors (n,3): equal-weight quadrature on the sphere."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def emitter_radiance(emitter: mi.Emitter, d: mi.Vector3f) -> mi.Color3f:
    """Radiance of an environment emitter seen along ``d``."""
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(d))
    si.wi = -d
    return emitter.eval(si)


class Light:
    """The light around the container: ``ambient`` (one RGB) or ``sh`` (9 RGB coefficients)."""

    def __init__(self, kind: str, emitter: mi.Emitter):
        if kind not in LIGHTS[1:]:
            raise ReneusError(f"light={kind!r}: expected one of {', '.join(LIGHTS)}")
        self.kind = kind
        # Initialised by projecting the scene's emitter (exact for a constant one).
        dirs = fibonacci_directions(_PROJECTION_DIRECTIONS)
        d = mi.Vector3f(*(mi.Float(dirs[:, i].astype(np.float32)) for i in range(3)))
        L = np.broadcast_to(np.array(emitter_radiance(emitter, d), np.float64).reshape(3, -1), (3, len(dirs)))
        if kind == 'ambient':
            values = L.mean(axis=1)
        else:
            Y = np.array([np.broadcast_to(np.array(y, np.float64), (len(dirs),)) for y in sh_basis(d)])
            values = (4.0 * np.pi / len(dirs)) * (Y @ L.T)    # (9, 3)
        self.coefficients = mi.Float(values.astype(np.float32).ravel())

    @property
    def name(self) -> str:
        return 'light.radiance' if self.kind == 'ambient' else 'light.sh'

    def eval(self, d: mi.Vector3f) -> mi.Color3f:
        c = self.coefficients
        if self.kind == 'ambient':
            return mi.Color3f(*(dr.gather(mi.Float, c, i) for i in range(3)))
        L = dr.zeros(mi.Color3f, dr.width(d))
        for k, y in enumerate(sh_basis(d)):
            L += y * mi.Color3f(*(dr.gather(mi.Float, c, 3 * k + i) for i in range(3)))
        # Negative radiance is not light: an SH fit can ring below zero.
        return dr.maximum(L, 0.0)

    def mean(self) -> np.ndarray:
        """Mean radiance over the sphere (RGB): what a uniform room of the same power shows."""
        c = np.array(self.coefficients, np.float64).reshape(-1, 3)
        return c[0] if self.kind == 'ambient' else c[0] * _Y00


def _cross_matrix(v) -> mi.Matrix3f:
    return mi.Matrix3f(0.0, -v.z, v.y,
                       v.z, 0.0, -v.x,
                       -v.y, v.x, 0.0)


class ContainerPose:
    """A rigid transform and per-axis scale of the container about ``pivot``."""

    def __init__(self, pivot):
        self.pivot = mi.ScalarPoint3f(*map(float, pivot))
        self.translation = dr.zeros(mi.Float, 3)
        self.rotation = dr.zeros(mi.Float, 3)
        self.log_scale = dr.zeros(mi.Float, 3)

    def params(self) -> dict:
        return {'container.translation': self.translation, 'container.rotation': self.rotation,
                'container.log_scale': self.log_scale}

    @staticmethod
    def _vector(array) -> mi.Vector3f:
        return mi.Vector3f(*(dr.gather(mi.Float, array, i) for i in range(3)))

    def _linear(self):
        """(R, s): the rotation matrix (Rodrigues) and the per-axis scale, differentiable at 0."""
        r = self._vector(self.rotation)
        θ2 = dr.squared_norm(r)
        θ = dr.sqrt(dr.maximum(θ2, 1e-12))
        small = θ2 < 1e-6
        a = dr.select(small, 1.0 - θ2 / 6.0, dr.sin(θ) / θ)
        b = dr.select(small, 0.5 - θ2 / 24.0, (1.0 - dr.cos(θ)) / dr.maximum(θ2, 1e-12))
        K = _cross_matrix(r)
        R = dr.identity(mi.Matrix3f) + a * K + b * (K @ K)
        return R, dr.exp(self._vector(self.log_scale))

    def to_container(self, o: mi.Point3f, d: mi.Vector3f):
        """World rays in the frame of the container as loaded: (origin, unnormalised direction)."""
        R, s = self._linear()
        c = mi.Point3f(self.pivot)
        Rt = R.T
        o_c = (Rt @ mi.Vector3f(o - c - self._vector(self.translation))) / s + c
        return mi.Point3f(o_c), mi.Vector3f((Rt @ d) / s)

    def to_world(self, x: mi.Point3f) -> mi.Point3f:
        """A point of the container as loaded, where the pose puts it."""
        R, s = self._linear()
        c = mi.Point3f(self.pivot)
        return mi.Point3f(R @ (s * mi.Vector3f(x - c)) + c + self._vector(self.translation))

    def normal_to_world(self, n: mi.Vector3f) -> mi.Vector3f:
        """A normal of the container as loaded, in the world (inverse transpose of R diag(s))."""
        R, s = self._linear()
        return dr.normalize(R @ (n / s))

    def matrix(self) -> np.ndarray:
        """The 4x4 world transform of the container (NumPy, for writing the refined mesh)."""
        with dr.suspend_grad():
            R, s = self._linear()
            t = np.array(self._vector(self.translation), np.float64).ravel()
            Rm = np.array(R, np.float64).reshape(3, 3)
            sm = np.array(s, np.float64).ravel()
        c = np.array(self.pivot, np.float64)
        M = np.eye(4)
        M[:3, :3] = Rm * sm[None, :]
        M[:3, 3] = c + t - M[:3, :3] @ c
        return M


class BoardShading:
    """The light that reaches the backdrop, as a gain on its emission: a grid of log-gains over
    its uv square (bilinear), starting at 1.

    The scene's board is its print lit evenly (the capture measures the print away from the
    container), but under and around a container the photographs show it shaded: the glass
    passes (1 - R)^2 of the tent's light, focuses some into caustics, and the specimen casts a
    shadow. Seen from every view through the glass, a board point's gain is one value, so the
    photographs fix it; without it the field can only darken the glass itself, and fog fills
    the block (docs/constants.md). Every backdrop shape shares the grid through its own uv."""

    NAME = 'board.shading'

    def __init__(self, texels: int, aspect: float):
        #: Texels along u and v: ``texels`` along the longer side, square texels.
        self.size = (texels, max(1, round(texels / aspect))) if aspect >= 1 else \
            (max(1, round(texels * aspect)), texels)
        self.log_gain = dr.zeros(mi.Float, self.size[0] * self.size[1])

    def gain(self, uv: mi.Point2f, active: mi.Bool) -> mi.Float:
        w, h = self.size
        x = dr.clip(uv.x * w - 0.5, 0.0, w - 1.0)
        y = dr.clip(uv.y * h - 0.5, 0.0, h - 1.0)
        x0, y0 = mi.UInt32(dr.floor(x)), mi.UInt32(dr.floor(y))
        x1, y1 = dr.minimum(x0 + 1, w - 1), dr.minimum(y0 + 1, h - 1)
        fx, fy = x - dr.floor(x), y - dr.floor(y)
        g = 0.0
        for xi, yi, wt in ((x0, y0, (1 - fx) * (1 - fy)), (x1, y0, fx * (1 - fy)),
                           (x0, y1, (1 - fx) * fy), (x1, y1, fx * fy)):
            g += wt * dr.gather(mi.Float, self.log_gain, yi * w + xi, active)
        return dr.exp(g)


def _uv_aspect(shape) -> float:
    """World length of a shape's u side over its v side (a rectangle's, or a quad mesh's)."""
    si = shape.eval_parameterization(mi.Point2f([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]))
    p = np.array(si.p, np.float64).T
    if not np.all(np.array(si.is_valid())):
        return 1.0
    return float(np.linalg.norm(p[1] - p[0]) / max(np.linalg.norm(p[2] - p[0]), 1e-12))


class Surroundings:
    """The container's interfaces (their IORs, the media's absorption, its pose), the light and
    the backdrop of one scene, owned by the integrator."""

    def __init__(self, interfaces: Interfaces | None, shapes: list, emitter: mi.Emitter, *,
                 backdrop: list = (), light: str = 'emitter', pose: bool = False, pivot=(0.0, 0.0, 0.0),
                 crease_angle: float = CREASE_ANGLE, board_texels: int = 0, absorption: bool = False):
        #: The nested interfaces (None: no container, mode 'neus').
        self.interfaces = interfaces
        self.container_eta = self.inner_ior = self.sigma_a = None
        if interfaces is not None:
            #: The IOR inside the outermost interface (the glass), and inside the inner ones.
            self.container_eta = mi.Float(interfaces.ior[0])
            self.inner_ior = mi.Float(interfaces.ior[1:]) if interfaces.count > 1 else None
            #: Beer-Lambert absorption of each region inside, RGB per scene unit (None: all clear).
            if absorption or any(s is not None for s in interfaces.sigma_a):
                self.sigma_a = mi.Float(np.ravel([s or (0.0, 0.0, 0.0) for s in interfaces.sigma_a]))
            self._outer = mi.UInt32(interfaces.outer)
            self._group = list(zip(shapes, interfaces.group_of_shape()))
        self.shapes = shapes
        #: The container alone, and the backdrop shapes (None without): see the module docstring.
        self.container = scene_of(shapes)
        self.backdrop = scene_of(list(backdrop)) if backdrop else None
        #: The shading normals of each mesh's triangle corners (the container's optics).
        self.normals = {shape: shading_normals(shape, crease_angle) for shape in shapes
                        if isinstance(shape, mi.Mesh)}
        self.emitter = emitter
        self.light = None if light == 'emitter' else Light(light, emitter)
        self.pose = ContainerPose(pivot) if pose else None
        self.shading = None
        if backdrop and board_texels:
            self.shading = BoardShading(board_texels, _uv_aspect(backdrop[0]))

    @property
    def conserving(self) -> bool:
        """Whether the empty container brings every ray the one radiance outside: every ray
        leaving it sees the same (no backdrop, a constant emitter or an ambient light) and its
        medium absorbs nothing, so that a ray inside, however it is reflected, ends with it."""
        if self.backdrop is not None or self.sigma_a is not None:
            return False
        if self.light is not None:
            return self.light.kind == 'ambient'
        return self.emitter.class_name() == 'ConstantBackgroundEmitter'

    def mesh(self):
        """The container as the scene loaded it (world coordinates), as one trimesh."""
        parts = []
        for shape in self.shapes:
            params = mi.traverse(shape)
            parts.append(trimesh.Trimesh(np.array(params['vertex_positions']).reshape(-1, 3),
                                         np.array(params['faces']).reshape(-1, 3), process=False))
        return trimesh.util.concatenate(parts)

    def posed_mesh(self):
        """The container where its pose puts it (as loaded without one), one vertex per
        triangle corner carrying the normal light is bent by there: written out, the file
        refracts as this container does (a refined rounded block keeps its smooth normals)."""
        parts = []
        for shape, table in self.normals.items():
            params = mi.traverse(shape)
            corners = np.array(params['vertex_positions']).reshape(-1, 3)[
                np.array(params['faces']).reshape(-1, 3)].reshape(-1, 3)
            parts.append((corners, np.array(table).reshape(-1, 3)))
        x, n = (np.concatenate(a).astype(np.float64) for a in zip(*parts))
        if self.pose is not None:
            M = self.pose.matrix()
            x = x @ M[:3, :3].T + M[:3, 3]
            n = n @ np.linalg.inv(M[:3, :3])   # normals go by the inverse transpose
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return trimesh.Trimesh(x, np.arange(len(x)).reshape(-1, 3), vertex_normals=n, process=False)

    def params(self) -> dict:
        """The refinable arrays, by their ``mi.traverse`` names (under the integrator)."""
        out = {}
        for name, array in (('container.eta', self.container_eta), ('container.inner_ior', self.inner_ior),
                            ('container.sigma_a', self.sigma_a)):
            if array is not None:
                out[name] = array
        if self.pose is not None:
            out.update(self.pose.params())
        if self.light is not None:
            out[self.light.name] = self.light.coefficients
        if self.shading is not None:
            out[BoardShading.NAME] = self.shading.log_gain
        return out

    # The container's optics, per ray (Dr.Jit); region 0 is the world, g + 1 inside interface g.
    def group(self, si: mi.SurfaceInteraction3f) -> mi.UInt32:
        """The interface each hit belongs to."""
        g = dr.zeros(mi.UInt32, dr.width(si.t))
        for shape, group in self._group:
            if group:
                g = dr.select(si.shape == mi.ShapePtr(shape), group, g)
        return g

    def ior(self, region: mi.UInt32) -> mi.Float:
        """The absolute IOR of each region."""
        n = dr.select(region == 1, dr.gather(mi.Float, self.container_eta, dr.zeros(mi.UInt32, dr.width(region))),
                      1.0)
        if self.inner_ior is not None:
            n = dr.select(region >= 2, dr.gather(mi.Float, self.inner_ior, dr.maximum(region, 2) - 2), n)
        return n

    def eta(self, group: mi.UInt32) -> mi.Float:
        """The relative IOR of each interface, inside over outside (as its dielectric's η)."""
        return self.ior(group + 1) / self.ior(dr.gather(mi.UInt32, self._outer, group))

    def beyond(self, group: mi.UInt32, entering: mi.Bool) -> mi.UInt32:
        """The region a ray refracted through an interface goes into."""
        return dr.select(entering, group + 1, dr.gather(mi.UInt32, self._outer, group))

    def absorption(self, region: mi.UInt32) -> mi.Color3f | None:
        """The absorption coefficient of each region (None: no region absorbs)."""
        if self.sigma_a is None:
            return None
        i = 3 * (dr.maximum(region, 1) - 1)
        return dr.select(region > 0, mi.Color3f(*(dr.gather(mi.Float, self.sigma_a, i + c) for c in range(3))), 0.0)

    def attenuation(self, region: mi.UInt32, t: mi.Float) -> mi.Color3f:
        """What a segment of length ``t`` in each region lets through (Beer-Lambert)."""
        σ = self.absorption(region)
        return mi.Color3f(1.0) if σ is None else dr.exp(-σ * t)

    def ambient(self, d: mi.Vector3f) -> mi.Color3f:
        """Radiance arriving from direction ``d`` outside the container (C_out)."""
        return emitter_radiance(self.emitter, d) if self.light is None else self.light.eval(d)

    def outside(self, o: mi.Point3f, d: mi.Vector3f, active: mi.Bool | bool = True) -> mi.Color3f:
        """Radiance seen from ``o`` (outside the container) looking along ``d``: the emission of
        the backdrop where the ray meets it (its front; the back of an area emitter is black),
        else C_out."""
        L = self.ambient(d)
        if self.backdrop is None:
            return L
        si = self.backdrop.ray_intersect(mi.Ray3f(o, d), active)
        hit = si.is_valid()
        emitted = si.emitter(self.backdrop).eval(si, hit)
        if self.shading is not None:
            emitted *= self.shading.gain(si.uv, hit)
        return dr.select(hit, emitted, L)

    def model_groups(self, learning_rate: float) -> list[ParamGroup]:
        """What is fitted with the field as part of the model: the board's shading (its
        learning rate :data:`SHADING_LR_SCALE` times the run's)."""
        if self.shading is None:
            return []
        return [ParamGroup('board', (BoardShading.NAME,), learning_rate * SHADING_LR_SCALE)]

    def param_groups(self, refine) -> list[ParamGroup]:
        """The groups that ``refine`` (a :class:`~reneus_mi.config.RefineConfig`, the one these
        surroundings were built with) asks for: the IOR (within its range), the pose, the light;
        each at its own rate from ``refine.after``."""
        groups = []
        if refine.ior:
            groups.append(ParamGroup('ior', ('container.eta',), refine.ior_learning_rate, refine.after,
                                     tuple(refine.ior_range)))
        if refine.inner_ior and self.inner_ior is None:
            raise ReneusError('train.refine.inner_ior (--refine-inner-ior): the container has no inner '
                              "interface (a case's inner faces, a jar's liquid) whose IOR could be refined; "
                              'expected a container stated as nested interfaces (docs/containers.md)')
        if refine.inner_ior:
            groups.append(ParamGroup('inner_ior', ('container.inner_ior',), refine.ior_learning_rate, refine.after,
                                     (1.0, refine.ior_range[1])))
        if refine.absorption:
            groups.append(ParamGroup('absorption', ('container.sigma_a',), refine.absorption_learning_rate,
                                     refine.after, (0.0, float('inf'))))
        if self.pose is not None:
            groups.append(ParamGroup('pose', tuple(self.pose.params()), refine.pose_learning_rate, refine.after))
        if self.light is not None:
            groups.append(ParamGroup('light', (self.light.name,), refine.light_learning_rate, refine.after))
        return groups

    def values(self, names) -> dict:
        """The current values of the arrays ``names`` as plain numbers, with what reads better
        beside them (the scale of a log-scale, an SH light's mean): for logs and a run's result."""
        params = self.params()
        out = {}
        for name in names:
            value = np.array(params[name], np.float64).round(6).tolist()
            out[name] = value[0] if name == 'container.eta' else value
        if 'container.log_scale' in out:
            out['container.scale'] = np.exp(out['container.log_scale']).round(6).tolist()
        if 'light.sh' in out:
            out['light.mean'] = self.light.mean().round(6).tolist()
        return out

    def load(self, values: dict[str, np.ndarray], where: str) -> None:
        """Set the arrays from saved values (a checkpoint), each checked for its size."""
        for name, array in self.params().items():
            if name not in values:
                continue
            value = np.asarray(values[name], np.float32).ravel()
            if value.size != dr.width(array):
                raise ReneusError(f'{where}: {name} holds {value.size} values; expected {dr.width(array)}')
            mi.set_property(array, mi.Float(value))


# ------------------------------------------------------------ the scene's shapes
def scene_parts(scene: mi.Scene) -> tuple[list, list, list]:
    """The scene's shapes sorted: the container (smooth dielectrics), the backdrop (area
    emitters), the others (an error where the container matters)."""
    container, backdrop, other = [], [], []
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is not None and bsdf.class_name() == 'SmoothDielectric':
            container.append(shape)
        elif shape.is_emitter():
            backdrop.append(shape)
        else:
            other.append(shape)
    return container, backdrop, other


def shapes_bbox(shapes: list) -> mi.ScalarBoundingBox3f:
    """The union of the shapes' bounding boxes (invalid for none)."""
    bbox = mi.ScalarBoundingBox3f()
    for shape in shapes:
        bbox.expand(shape.bbox())
    return bbox


def surroundings_of(scene: mi.Scene, render, refine) -> 'Surroundings':
    """The container, light and backdrop of ``scene`` as ``render`` (a
    :class:`~reneus_mi.config.RenderConfig`) models them, with the parameters that ``refine`` (a
    :class:`~reneus_mi.config.RefineConfig`) fits (the pose, the light), checked: every shape a
    smooth dielectric (the container's interfaces, :mod:`reneus_mi.render.interfaces`) or an
    area emitter."""
    shapes, backdrop, other = scene_parts(scene)
    if scene.environment() is None:
        raise ReneusError("reneus integrator: the scene has no environment emitter; expected "
                          "<emitter type=\"constant\"> with the ambient radiance C_out (0.8 in the paper)")
    if render.mode == 'neus':
        return Surroundings(None, shapes, scene.environment(), backdrop=backdrop, light=refine.light_model(),
                            board_texels=render.board_texels)
    for shape in other:
        bsdf = shape.bsdf()
        name = bsdf.class_name() if bsdf is not None else 'no'
        raise ReneusError(f"reneus integrator: shape '{shape.id()}' has a {name} BSDF and no emitter; "
                          "every shape must be the container, with a smooth 'dielectric' BSDF, or a "
                          "backdrop with an 'area' emitter (the board the container stands on)")
    if not shapes:
        raise ReneusError('reneus integrator: the scene has no shape with a dielectric BSDF; expected '
                          'the container as such a shape')
    if refine.pose and not all(isinstance(sh, mi.Mesh) for sh in shapes):
        raise ReneusError('reneus integrator: refine.pose needs the container as triangle meshes '
                          '(ply, obj); the scene has another kind of shape')
    bbox = shapes_bbox(shapes)
    return Surroundings(interfaces_of(shapes), shapes, scene.environment(), backdrop=backdrop,
                        light=refine.light_model(), pose=refine.pose, pivot=0.5 * (bbox.min + bbox.max),
                        crease_angle=render.crease_angle, board_texels=render.board_texels,
                        absorption=refine.absorption)
