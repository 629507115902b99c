"""What surrounds the field, and what the paper takes as known: the container's IOR
and pose, and the light (beyond the paper: Sec. 5 names them as its limitation); the pose
(:mod:`~reneus_mi.render.pose`), the light (:mod:`~reneus_mi.render.light`) and the board's
shading (:mod:`~reneus_mi.render.board_shading`) in modules of their own.

The ``reneus`` integrator owns one :class:`Surroundings` per scene, built from
the scene when it first renders it: the IOR from the container's ``dielectric``
BSDF, the pose at identity (the container as the scene places it), the light
from the scene's environment emitter. Their values are Dr.Jit arrays that
``mi.traverse(scene)`` shows under the names of :meth:`Surroundings.params`
(``container.eta``, ``container.translation``, ``light.sh``, ...); the trainer
refines those a run asks for, like the field's own parameters.

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

from reneus_mi.geometry.container import CREASE_ANGLE, container_edges, is_container, scene_of, shading_normals
from reneus_mi.render.bow import ContainerBow
from reneus_mi.render.board_shading import SHADING_LR_SCALE, BoardShading, uv_aspect
from reneus_mi.render.interfaces import Interfaces, interfaces_of
from reneus_mi.render.light import Light, emitter_radiance
from reneus_mi.render.pose import ContainerPose
from reneus_mi.render.step_state import refined
from reneus_mi.render.walls import ContainerWalls
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.param_groups import ParamGroup


class Surroundings:
    """The container's interfaces (their IORs, the media's absorption, its pose), the light and
    the backdrop of one scene, owned by the integrator."""

    def __init__(self, interfaces: Interfaces | None, shapes: list, emitter: mi.Emitter, *,
                 backdrop: list = (), light: str = 'emitter', pose: bool = False, pivot=(0.0, 0.0, 0.0),
                 crease_angle: float = CREASE_ANGLE, board_texels: int = 0, absorption: bool = False,
                 edge_margin: float = 0.0, wall: bool = False, bow: bool = False):
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
        meshes = [shape for shape in shapes if isinstance(shape, mi.Mesh)]
        #: The container's edges (``container_edges``) where rays are flagged: the segments'
        #: ends a and b (None: none), and the meshes whose faces on a rounding are flagged whole.
        self.edge_segments = None
        self.edge_margin = edge_margin
        edges = [(shape, *container_edges(shape, crease_angle, edge_margin)) for shape in meshes] \
            if edge_margin > 0.0 else []
        #: The bulge of a solid block's faces (None: flat as loaded). It cuts the block finer, so
        #: the edges are found before (the finer facets of a rounding would each be one) and its
        #: faces' flags handed to their pieces, and the shading normals are its own.
        self.bow = None
        if bow:
            if interfaces is None or interfaces.count > 1 or len(shapes) > 1:
                raise ReneusError('model.render.bow: the container is not one solid block '
                                  '(nested interfaces or several shapes); expected a block whose faces '
                                  'may bulge (docs/containers.md)')
            self.bow = ContainerBow(shapes[0], crease_angle)
            edges = [(shape, segments, self.bow.pieces(faces)) for shape, segments, faces in edges]
        if sum(len(segments) for _, segments, _ in edges):
            ends = np.concatenate([segments for _, segments, _ in edges]).astype(np.float32)
            self.edge_segments = tuple(mi.Point3f(*(mi.Float(ends[:, end, i]) for i in range(3))) for end in (0, 1))
        self.rounded = [(shape, mi.Bool(faces)) for shape, _, faces in edges if faces.any()]
        #: The container alone, and the backdrop shapes (None without): see the module docstring.
        self.container = scene_of(shapes)
        self.backdrop = scene_of(list(backdrop)) if backdrop else None
        #: The shading normals of each mesh's triangle corners (the container's optics).
        self.normals = {shape: self.bow.table if self.bow is not None else shading_normals(shape, crease_angle)
                        for shape in meshes}
        self.emitter = emitter
        self.light = None if light == 'emitter' else Light(light, emitter)
        self.pose = ContainerPose(pivot) if pose else None
        self.walls = ContainerWalls(shapes, interfaces.group_of_shape(), interfaces.outer) if wall else None
        self.shading = None
        if backdrop and board_texels:
            self.shading = BoardShading(board_texels, uv_aspect(backdrop[0]))

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
            normals = np.array(table, np.float64).reshape(-1, 3)
            if self.bow is not None and shape is self.bow.shape:
                normals = self.bow.tilted(corners, normals)
            parts.append((corners, normals))
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
        if self.walls is not None:
            out.update(self.walls.params())
        if self.bow is not None:
            out.update(self.bow.params())
        if self.pose is not None:
            out.update(self.pose.params())
        if self.light is not None:
            out[self.light.name] = self.light.coefficients
        if self.shading is not None:
            out[BoardShading.NAME] = self.shading.log_gain
        return out

    # The container's optics, per ray (Dr.Jit); region 0 is the world, g + 1 inside interface g.
    # ``lanes``: the rays whose gradients reach the refined quantities (StepState.refining).
    def group(self, si: mi.SurfaceInteraction3f) -> mi.UInt32:
        """The interface each hit belongs to."""
        g = dr.zeros(mi.UInt32, dr.width(si.t))
        for shape, group in self._group:
            if group:
                g = dr.select(si.shape == mi.ShapePtr(shape), group, g)
        return g

    def ior(self, region: mi.UInt32, lanes: mi.Bool | None = None) -> mi.Float:
        """The absolute IOR of each region."""
        n = dr.select(region == 1, dr.gather(mi.Float, self.container_eta, dr.zeros(mi.UInt32, dr.width(region))),
                      1.0)
        if self.inner_ior is not None:
            n = dr.select(region >= 2, dr.gather(mi.Float, self.inner_ior, dr.maximum(region, 2) - 2), n)
        return refined(n, lanes)

    def eta(self, group: mi.UInt32, lanes: mi.Bool | None = None) -> mi.Float:
        """The relative IOR of each interface, inside over outside (as its dielectric's η)."""
        return self.ior(group + 1, lanes) / self.ior(dr.gather(mi.UInt32, self._outer, group), lanes)

    def beyond(self, group: mi.UInt32, entering: mi.Bool) -> mi.UInt32:
        """The region a ray refracted through an interface goes into."""
        return dr.select(entering, group + 1, dr.gather(mi.UInt32, self._outer, group))

    def absorption(self, region: mi.UInt32, lanes: mi.Bool | None = None) -> mi.Color3f | None:
        """The absorption coefficient of each region (None: no region absorbs)."""
        if self.sigma_a is None:
            return None
        i = 3 * (dr.maximum(region, 1) - 1)
        σ = mi.Color3f(*(dr.gather(mi.Float, self.sigma_a, i + c) for c in range(3)))
        return dr.select(region > 0, refined(σ, lanes), 0.0)

    def attenuation(self, region: mi.UInt32, t: mi.Float, lanes: mi.Bool | None = None) -> mi.Color3f:
        """What a segment of length ``t`` in each region lets through (Beer-Lambert)."""
        σ = self.absorption(region, lanes)
        return mi.Color3f(1.0) if σ is None else dr.exp(-σ * t)

    def ambient(self, d: mi.Vector3f, lanes: mi.Bool | None = None) -> mi.Color3f:
        """Radiance arriving from direction ``d`` outside the container (C_out)."""
        return emitter_radiance(self.emitter, d) if self.light is None else refined(self.light.eval(d), lanes)

    @property
    def flags_edges(self) -> bool:
        """Whether rays near the container's edges are flagged (``edge_margin``, and edges)."""
        return self.edge_segments is not None or bool(self.rounded)

    def near_edge(self, p: mi.Point3f, si: mi.SurfaceInteraction3f) -> mi.Bool:
        """Whether each hit ``si`` at ``p`` lies on a rounding of the container or within
        ``edge_margin`` of an edge's segment, as loaded (the pose, a fraction of a millimetre,
        is left out)."""
        near = dr.zeros(mi.Bool, dr.width(p.x))
        for shape, faces in self.rounded:
            near |= (si.shape == mi.ShapePtr(shape)) & dr.gather(mi.Bool, faces, si.prim_index, si.is_valid())
        return near if self.edge_segments is None else near | self._near_segment(p)

    def _near_segment(self, p: mi.Point3f) -> mi.Bool:
        a, b = self.edge_segments
        count = dr.opaque(mi.UInt32, dr.width(a.x))
        r2 = dr.opaque(mi.Float, self.edge_margin ** 2)

        def body(k, near):
            e0, e1 = dr.gather(mi.Point3f, a, k), dr.gather(mi.Point3f, b, k)
            e = e1 - e0
            t = dr.clip(dr.dot(p - e0, e) / dr.maximum(dr.squared_norm(e), 1e-20), 0.0, 1.0)
            return k + 1, near | (dr.squared_norm(p - (e0 + t * e)) < r2)
        return dr.while_loop((mi.UInt32(0), dr.zeros(mi.Bool, dr.width(p.x))), lambda k, near: k < count, body)[1]

    def outside(self, o: mi.Point3f, d: mi.Vector3f, active: mi.Bool | bool = True,
                lanes: mi.Bool | None = None) -> mi.Color3f:
        """Radiance seen from ``o`` (outside the container) looking along ``d``: the emission of
        the backdrop where the ray meets it (its front; the back of an area emitter is black),
        else C_out."""
        L = self.ambient(d, lanes)
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
        """The groups that ``refine`` (a :class:`~reneus_mi.train.config.RefineConfig`, the one these
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
        if self.walls is not None:
            groups.append(ParamGroup('wall', (ContainerWalls.NAME,),
                                     refine.wall_learning_rate * float(self.walls.stated.max()), refine.after,
                                     self.walls.bounds()))
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
        if ContainerWalls.NAME in out:
            out['container.wall_stated'] = self.walls.stated.round(6).tolist()
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
        if is_container(shape):
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
    :class:`~reneus_mi.render.config.RenderConfig`) models them, with the parameters that ``refine`` (a
    :class:`~reneus_mi.train.config.RefineConfig`) fits (the pose, the light), checked: every shape a
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
                        absorption=refine.absorption, edge_margin=render.edge_margin, wall=refine.wall,
                        bow=render.bow)
