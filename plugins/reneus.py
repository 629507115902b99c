"""The ``reneus`` integrator: ReNeuS's hybrid renderer (Sec. 3.3 of the paper)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from reneus_mi.render.config import ModelConfig
from reneus_mi.train.config import RefineConfig
from reneus_mi.fields import Field
from reneus_mi.geometry.container import interpolated_normal
from reneus_mi.geometry.frame import FieldFrame
from reneus_mi.render.optics import interface
from reneus_mi.plugins.properties import read_properties
from reneus_mi.render.seeds import opaque_seed, salted_seed
from reneus_mi.render.step_state import StepState, refined
from reneus_mi.render.surroundings import Surroundings, scene_parts, shapes_bbox, surroundings_of
from reneus_mi.render.volume_rendering import volume_render
from reneus_mi.utils.errors import ReneusError

VARIANT = mi.variant()
#: Interfaces that ``terminal='trace'`` follows beyond the ray tree: a box's internal
#: reflections rarely need more, and each one left costs only weight below the cutoff.
TRACE_BOUNCES = 8
#: Weight below which ``terminal='trace'`` stops following a ray (it then sees outside straight on).
TRACE_CUTOFF = 1e-3
#: Offset of the random streams of ``terminal='trace'`` from those of the tree's roulette.
TRACE_SALT = 1 << 16

#: Names of the AOV channels, after R, G, B (and alpha where the film has it).
AOV_NAMES = ('mask', 'sparsity', 'nx', 'ny', 'nz')


@dataclass
class RayTreeResult:
    """What :meth:`ReNeuSIntegrator.render_rays` returns per camera ray."""
    color: mi.Color3f
    """The pixel value 𝒢(C(ℓ)) = C^(1/γ): what photographs are compared with."""
    L: mi.Color3f
    """Linear radiance C(ℓ) accumulated over the ray tree (before gamma)."""
    mask: mi.Bool
    """Whether the camera ray meets the container (the paper's M_in)."""
    sparsity: mi.Float
    """Σ over the ray's inside segments of (1 - T_ℓ): the summand of L_trans."""
    eikonal: mi.Float
    """Σ over every sample of the ray's inside segments of (|∇g| - 1)²."""
    n_samples: mi.Float
    """Number of samples behind ``eikonal``."""
    normal: mi.Vector3f
    """Normals of the inside segments, accumulated with the same weights as L."""
    nearest: mi.Float
    """Σ over the ray's inside segments that miss the surface (g > 0 everywhere) of the SDF where
    each passes nearest it, weighted as L (with its gradient; the ``reach`` term of the loss)."""
    nearest_color: mi.Color3f
    """The pixel value those segments would bring if they ended there (no gradient)."""
    near_edge: mi.Bool
    """Whether the ray enters or leaves the container near one of its crease edges
    (``edge_margin``; False without one): training leaves it out of the colour loss."""


class ReNeuSIntegrator(mi.ad.integrators.common.ADIntegrator):
    r"""
    ReNeuS's hybrid renderer (Sec. 3.3): ray tracing through a transparent container (the
    scene's shapes with a smooth ``dielectric`` BSDF), NeuS volume rendering of a field inside
    it. At every interface both the reflected and the refracted ray are followed, weighted by
    Fresnel's R and 1 - R, up to ``max_depth`` interface events; a ray that leaves takes the
    backdrop it meets (shapes with an ``area`` emitter) or the environment emitter's light.
    The model in full, the depth and the radiance units: ``docs/integrator.md``.

    .. pluginparameters::

     * - preset
       - |string|
       - Named configuration the other properties override: ``paper``, ``cpu``,
         ``demo``, ... (Default: ``paper``)
     * - mode, max_depth, terminal, gamma, aovs
       - |string|, |int|, |string|, |float|, |bool|
       - The ray tree (:class:`~reneus_mi.render.config.RenderConfig`): ``reneus``,
         ``neus`` or ``neus_plus``; D_re; ``trace``, ``ambient`` or ``black``; the output
         is C^(1/gamma); AOVs ``mask``, ``sparsity``, ``nx, ny, nz``.
     * - crease_angle
       - |float|
       - Container faces that meet at more than this angle (degrees) are not smoothed
         together: a box refracts through flat faces even when written with 8 shared
         vertices. (Default: 30, like Blender's auto-smooth)
     * - n_coarse, n_fine, n_upsample_steps, upsample_s, occupancy_*
       - |int|, |int|, |int|, |float|, ...
       - Samples per inside segment and the occupancy grid that skips empty space
         (:class:`~reneus_mi.render.ray_samplers.SamplerConfig`).
     * - field
       - |string|
       - The field's kind (``neus``, ``sphere``, ``box``, ``torus``, ...) or the
         path of a field saved with ``Field.save``/a checkpoint. Properties named
         ``field_<name>`` set the kind's configuration field ``<name>``.
         (Default: the preset's)
     * - field_center
       - |point|
       - World position of the centre of the field's unit bounding sphere.
         (Default: 0, 0, 0)
     * - field_scale
       - |float|
       - World radius of the field's unit bounding sphere. (Default: 1)
     * - dataset
       - |string|
       - Folder of the photographs and cameras that ``reneus_mi.optimize``
         fits the field to. Not used for rendering. (Default: none)

    **Settings.** Every property is a field of :class:`reneus_mi.render.config.ModelConfig`
    under the same name: ``preset`` picks a named configuration
    (:mod:`reneus_mi.presets`), and the properties given override it.

    The field's parameters appear in ``mi.traverse(scene)`` under the
    integrator's id (e.g. ``field.sdf.weights``). They are the field's own
    arrays: ``params.update()`` writes into the field, ``mi.render(scene,
    params=params)`` differentiates with respect to them, and after training
    ``mi.traverse`` shows the trained values. Once the integrator has seen its
    scene (:meth:`bind`, or a first render) the container's IOR
    ``container.eta`` appears beside them (and its medium's absorption
    ``container.sigma_a``), and the container's pose and the light
    where the integrator is told to refine them (:meth:`configure` with a
    :class:`~reneus_mi.train.config.RefineConfig`; :mod:`reneus_mi.render.surroundings`).
    """

    def __init__(self, props: mi.Properties):
        # ADIntegrator's constructor would read max_depth (its own default, untyped): skipped.
        mi.CppADIntegrator.__init__(self, props)
        props = read_properties(props)
        self.preset, self.frame, self.dataset = props.preset, props.frame, props.dataset
        self.state = StepState()
        self.model, self.field, self.refine, self._bound = None, None, RefineConfig(), None
        self.configure(props.model, props.field)

    def configure(self, model: ModelConfig | None = None, field: Field | None = None,
                  refine: RefineConfig | None = None) -> None:
        """Render with ``model`` (default: the current one) and ``field``; the surroundings'
        parameters that ``refine`` fits (default: the current ones) are made.

        Without ``field`` the current field is kept where ``model.field`` is its configuration,
        and a fresh one built from ``model.field`` otherwise; a given field (e.g. a trained one,
        :func:`~reneus_mi.fields.load_field`) sets ``model.field`` to its own configuration.
        """
        model = model or self.model
        self.refine = refine or self.refine
        if field is not None:
            model = dataclasses.replace(model, field=field.Config(**field.config()))
        elif self.model is not None and model.field == self.model.field:
            field = self.field
        self.model = model
        self.field = field if field is not None else model.field.setup()
        self.sampler = model.sampler.setup()
        # The surroundings follow the model and what is refined: built anew at the next bind.
        self._bound = None

    # ------------------------------------------------------------ Mitsuba API
    def aov_names(self):
        return list(AOV_NAMES) if self.model.render.aovs else []

    def traverse(self, cb):
        for key, value in self.params().items():
            cb.put(key, value, mi.ParamFlags.Differentiable)

    def params(self) -> dict:
        """The integrator's arrays as ``mi.traverse`` names them: the field's, and the
        surroundings' once bound to a scene."""
        out = dict(self.field.params())
        if self._bound is not None:
            out.update(self._bound[1].params())
        return out

    def traverse_keys(self, params: mi.SceneParameters) -> dict[str, str]:
        """The keys of the integrator's arrays in ``params`` (``mi.traverse`` of its scene), by
        their names here: ``sdf.weights`` -> ``field.sdf.weights`` under the integrator's id."""
        mine = [key for key, (_, _, node, _) in params.properties.items() if node is self]
        names = list(self.params())
        if len(mine) != len(names):
            raise ReneusError(f'mi.traverse shows {len(mine)} arrays of the integrator, it has '
                              f'{len(names)}; expected the traversal of its scene, after bind()')
        # traverse() puts them in this order.
        return dict(zip(names, mine))

    def parameters_changed(self, keys):
        # SceneParameters wrote the new values into the field's own arrays.
        pass

    def to_string(self):
        r, s = self.model.render, self.model.sampler
        return (f'ReNeuSIntegrator[mode={r.mode}, max_depth={r.max_depth}, terminal={r.terminal}, '
                f'samples={s.n_coarse}+{s.n_fine}, field={type(self.field).__name__}]')

    def sample(self, mode, scene, sampler, ray, δL=None, state_in=None, active=True, **kwargs):
        result = self.render_rays(scene, mi.Ray3f(ray), active=active)
        aovs = []
        if self.model.render.aovs:
            n = result.normal
            aovs = [mi.Float(result.mask), result.sparsity, n.x, n.y, n.z]
        return dr.select(active, result.color, 0.0), active, aovs, None

    # ------------------------------------------------------------ the method
    def begin_step(self, state: StepState) -> None:
        """Take the schedule values of a training step (the trainer calls this once per step)."""
        self.state = state
        self.field.set_step(state.step if state.schedule is None else state.schedule)
        self.sampler.update(self.field, state.step)

    def render_rays(self, scene: mi.Scene, ray: mi.Ray3f, active: mi.Bool | bool = True) -> RayTreeResult:
        """Render camera rays (world space): the pixel values and the per-ray loss terms.

        This is the algorithm; :meth:`sample` (``mi.render``) and the trainer
        both come here. The schedule of the current training step is
        :attr:`state` (see :meth:`begin_step`).
        """
        surroundings = self.bind(scene)
        for moving in (surroundings.walls, surroundings.bow):
            if moving is not None:
                moving.sync(surroundings.container)
        n = dr.width(ray.o)
        jitter = None
        if self.state.seed is not None:
            jitter = mi.PCG32(n, initstate=opaque_seed(self.state.seed)).next_float32()
        acc = _Accumulator(n)
        rays = _Rays(o=mi.Point3f(ray.o), d=mi.Vector3f(ray.d), β=dr.ones(mi.Color3f, n),
                     camera=dr.arange(mi.UInt32, n), region=dr.zeros(mi.UInt32, n))
        rays = rays.take(dr.compress(dr.full(mi.Bool, True, n) & active))
        if self.model.render.mode == 'neus':
            self._trace_neus(surroundings, rays, acc, jitter)
        else:
            self._trace_container(surroundings, rays, acc, jitter)
        L = acc.result()
        return RayTreeResult(color=self.tonemap(L), L=L, mask=acc.mask, sparsity=acc.sparsity,
                             eikonal=acc.eikonal, n_samples=acc.n_samples, normal=acc.normal,
                             nearest=acc.nearest, nearest_color=self.tonemap(acc.nearest_color),
                             near_edge=acc.near_edge)

    def _cos_anneal_ratio(self):
        """The step's ratio, opaque: kernels read it from memory rather than compile anew for each value."""
        ratio = self.state.cos_anneal_ratio
        return ratio if ratio == 1.0 else dr.opaque(mi.Float, ratio)

    def tonemap(self, L: mi.Color3f) -> mi.Color3f:
        """The paper's 𝒢(C) = C^(1/γ); the clamp keeps its derivative finite at 0."""
        gamma = self.model.render.gamma
        if gamma == 1.0:
            return L
        return dr.power(dr.maximum(L, 1e-6), 1.0 / gamma)

    # One generation of the ray tree per loop turn: rays are compressed to the
    # live ones so that the 2^k growth costs nothing for rays that escaped.
    def _trace_container(self, surroundings, rays, acc, jitter):
        render = self.model.render
        plus = render.mode == 'neus_plus'
        depth_limit = 1 if plus else render.max_depth
        outside, field = surroundings.outside, surroundings.interfaces.field
        σ_field = surroundings.absorption(mi.UInt32(field))
        for depth in range(depth_limit + 1):
            if rays.size == 0:
                return
            lanes = self._refining(rays)
            hit = self._intersect(surroundings, rays, lanes)
            if depth == 0:
                acc.mark_container(rays.camera, hit.valid)
            if depth <= 1 and surroundings.flags_edges:
                acc.mark_edge(rays.camera, hit.valid & surroundings.near_edge(hit.p, hit.si))
            leaving = hit.valid & (dr.dot(rays.d, hit.n) > 0)
            acc.add(rays.camera, rays.β * outside(rays.o, rays.d, ~hit.valid, lanes), ~hit.valid)
            in_field = hit.valid & (rays.region == field) & self.state.field
            T = self._render_inside(rays, hit.t, in_field, acc, jitter, σ_field)
            if surroundings.sigma_a is not None:
                # Segments in the other regions only absorb.
                T = dr.select(in_field, T, surroundings.attenuation(rays.region, hit.t, lanes))
            if plus and depth == 1:
                # NeuS+: the light beyond the segment arrives straight, unrefracted.
                acc.add(rays.camera, rays.β * T * outside(hit.p, rays.d, leaving, lanes), leaving)
                return
            if depth == depth_limit:
                if render.terminal == 'trace' and not surroundings.conserving:
                    self._trace_beyond(surroundings, rays, hit, T, acc, lanes)
                elif render.terminal != 'black':
                    # The empty container conserves uniform light: what 'trace' would gather is
                    # exactly the ambient.
                    acc.add(rays.camera, rays.β * T * outside(hit.p, rays.d, hit.valid, lanes), hit.valid)
                return
            rays = self._interface(surroundings, rays, hit, T, lanes, reflect=not plus, depth=depth)

    def _trace_beyond(self, surroundings, rays, hit, T, acc, lanes):
        """The light beyond the tree's last segment, through the container without the field.

        At each further interface the branch that leaves the container ends with what it meets
        outside (the backdrop or C_out) and the other goes on, weighted by R or 1 - R; after
        :data:`TRACE_BOUNCES` interfaces, or once its weight is below :data:`TRACE_CUTOFF`, a
        ray sees outside straight on, as ``ambient`` does. For a convex container no ray that
        left comes back, so this is the empty container's exact transport: what it drops is
        the field beyond the tree (its shadow on these paths)."""
        outside = surroundings.outside
        # Rays that met nothing took what they see in the tree.
        alive, β = hit.valid, rays.β * T
        for bounce in range(TRACE_BOUNCES + 1):
            stop = alive & ((bounce == TRACE_BOUNCES) | (_peak(dr.detach(β)) < TRACE_CUTOFF))
            acc.add(rays.camera, β * outside(hit.p, rays.d, stop, lanes), stop)
            if bounce == TRACE_BOUNCES:
                return
            go = alive & ~stop
            R, d_r, d_t, region_t = self._split(surroundings, rays, hit, lanes)
            # The branch that reaches the world ends there (from inside the refracted one, from
            # outside the reflected one); at an inner interface neither does, and one of the two
            # goes on, chosen with probability R (their weights' mean unchanged).
            out_t, out_r = region_t == 0, rays.region == 0
            d_out, w_out = dr.select(out_t, d_t, d_r), dr.select(out_t, 1.0 - R, dr.select(out_r, R, 0.0))
            escapes = go & (w_out > 0.0)
            acc.add(rays.camera, β * w_out * outside(_offset(hit.p, hit.n, d_out), d_out, escapes, lanes), escapes)
            reflect = out_t | (~out_r & (self._random(rays.size, bounce + TRACE_SALT) < R))
            keep = dr.compress(go & (w_out < 1.0))
            if dr.width(keep) == 0:
                return
            β = dr.gather(mi.Color3f, β * (1.0 - w_out), keep)
            reflect = dr.gather(mi.Bool, reflect, keep)
            d = dr.select(reflect, dr.gather(mi.Vector3f, d_r, keep), dr.gather(mi.Vector3f, d_t, keep))
            region = dr.select(reflect, dr.gather(mi.UInt32, rays.region, keep), dr.gather(mi.UInt32, region_t, keep))
            o = _offset(dr.gather(mi.Point3f, hit.p, keep), dr.gather(type(hit.n), hit.n, keep), d)
            rays = _Rays(o=o, d=d, β=β, camera=dr.gather(mi.UInt32, rays.camera, keep), region=region)
            lanes = self._refining(rays)
            hit = self._intersect(surroundings, rays, lanes)
            # A ray that grazed an edge and met nothing more sees outside from where it is.
            acc.add(rays.camera, β * outside(rays.o, rays.d, ~hit.valid, lanes), ~hit.valid)
            alive = hit.valid
            if surroundings.sigma_a is not None:
                β = dr.select(alive, β * surroundings.attenuation(rays.region, hit.t, lanes), β)

    def _intersect(self, surroundings, rays, lanes) -> '_Hit':
        """The rays' next container interface: distance, point, normals (differentiable in the
        pose and the walls' thickness)."""
        pose, container, walls = surroundings.pose, surroundings.container, surroundings.walls
        o, d = (rays.o, rays.d) if pose is None else pose.to_container(rays.o, rays.d, lanes)
        si = container.ray_intersect(mi.Ray3f(o, d))
        group = surroundings.group(si)
        t, vertex = si.t, None
        if walls is not None:
            # The inner face moved in along its normal by the change of the wall: dt/dw = -1 / (n · d),
            # held under 100 for rays that graze the face (within half a degree).
            shift, cos = walls.shift(group, lanes), dr.dot(si.n, d)
            t = t - shift / dr.select(dr.abs(cos) > 1e-2, cos, dr.select(cos < 0.0, -1e-2, 1e-2))
            vertex = walls.vertex(shift)
        # In the container's frame t is the same parameter along the ray when the direction
        # keeps its length.
        n_s = interpolated_normal(surroundings.normals, si, o + t * d, vertex)
        if surroundings.bow is not None:
            n_s = surroundings.bow.tilt(o + t * d, n_s, si.is_valid())
        if pose is not None:
            n, n_s = pose.normal_to_world(si.n, lanes), pose.normal_to_world(n_s, lanes)
        else:
            n = si.n
        return _Hit(t=t, p=mi.Point3f(rays.o + t * rays.d), n=n, n_s=n_s, valid=si.is_valid(), group=group, si=si)

    def _trace_neus(self, surroundings, rays, acc, jitter):
        # Plain NeuS: the field's unit bounding sphere, ambient beyond it.
        o = self.frame.to_field(rays.o)
        b = dr.dot(o, rays.d)
        disc = b * b - (dr.squared_norm(o) - 1.0)
        t_far = -b + dr.safe_sqrt(disc)
        inside = (disc > 0) & (t_far > 0)
        acc.mark_container(rays.camera, inside)
        t_near = dr.maximum(-b - dr.safe_sqrt(disc), 0.0)
        t_exit = dr.select(inside, t_far, 0.0) * self.frame.scale
        beyond = mi.Point3f(rays.o + rays.d * t_exit)
        rays.o = mi.Point3f(rays.o + rays.d * (t_near * self.frame.scale))
        T = self._render_inside(rays, (t_far - t_near) * self.frame.scale, inside, acc, jitter, None)
        acc.add(rays.camera, rays.β * T * surroundings.outside(beyond, rays.d, True, self._refining(rays)),
                mi.Bool(True))

    def _render_inside(self, rays, t_far, inside, acc, jitter, σ) -> mi.Color3f:
        """Volume render the rays' segments [0, t_far] where ``inside`` (the field's region), in
        a medium of absorption ``σ`` (world units; None: clear); return what reaches the segments'
        origins of the light from beyond them, the transmittance T times exp(-σ t_far) (1 elsewhere)."""
        T = dr.ones(mi.Color3f, rays.size)
        seg = dr.compress(inside)
        if dr.width(seg) == 0:
            return T
        s = rays.take(seg)
        t = dr.gather(mi.Float, t_far, seg)
        u = None if jitter is None else dr.gather(mi.Float, jitter, s.camera)
        σ = None if σ is None else refined(σ, self._refining(s))
        vr = volume_render(self.field, self.sampler, self.frame.to_field(s.o), s.d,
                           dr.zeros(mi.Float, dr.width(seg)), t / self.frame.scale, jitter=u,
                           cos_anneal_ratio=self._cos_anneal_ratio(),
                           sigma_a=None if σ is None else σ * self.frame.scale)
        acc.add(s.camera, s.β * vr.color, mi.Bool(True))
        acc.add_segment(s.camera, s.β, vr)
        beyond = mi.Color3f(vr.transmittance) if σ is None else vr.transmittance * dr.exp(-σ * t)
        dr.scatter(T, beyond, seg)
        return T

    def _random(self, n: int, salt: int) -> mi.Float:
        """``n`` uniform numbers of the step's seed and ``salt``: the same for the same step."""
        return mi.PCG32(n, initstate=opaque_seed(salted_seed(self.state.seed or 0, salt))).next_float32()

    def _refining(self, rays) -> mi.Bool | None:
        """Per ray, whether its gradient reaches the refined quantities (StepState.refining)."""
        lanes = self.state.refining
        return None if lanes is None else dr.gather(mi.Bool, lanes, rays.camera)

    @staticmethod
    def _split(surroundings, rays, hit, lanes):
        """At the rays' hits: Fresnel's R, the reflected and refracted directions, and the region
        the refracted ray goes into. Smooth containers bend light by their shading normals, as
        Mitsuba's dielectric does."""
        R, d_r, d_t = interface(rays.d, hit.n_s, surroundings.eta(hit.group, lanes))
        return R, d_r, d_t, surroundings.beyond(hit.group, dr.dot(rays.d, hit.n) < 0.0)

    def _interface(self, surroundings, rays, hit, T, lanes, reflect: bool, depth: int = 0):
        """Spawn the next generation: reflected (β·T·R) and refracted (β·T·(1-R)) rays, each in
        the region it goes into."""
        R, d_r, d_t, region_t = self._split(surroundings, rays, hit, lanes)
        β = rays.β * T
        if reflect:
            β_r, β_t = β * R, β * (1.0 - R)
        else:
            β_r, β_t = dr.zeros(mi.Color3f, rays.size), dr.select(R < 1.0, β, 0.0)
        # Candidates 0..n-1 are the reflected rays, n..2n-1 the refracted ones.
        n = rays.size
        j = dr.arange(mi.UInt32, 2 * n)
        # The count reaches the kernel as data: it changes from step to step.
        half = dr.opaque(mi.UInt32, n)
        refracted = j >= half
        lane = dr.select(refracted, j - half, j)
        β_all = dr.select(refracted, dr.gather(mi.Color3f, β_t, lane), dr.gather(mi.Color3f, β_r, lane))
        alive = dr.gather(mi.Bool, hit.valid, lane) & (_peak(dr.detach(β_all)) > 0.0)
        threshold = self.model.render.rr_threshold
        if threshold > 0.0:
            # Russian roulette: a branch of weight β < threshold survives with probability
            # β / threshold and then carries weight threshold; the tree's mean is unchanged.
            p = dr.minimum(_peak(dr.detach(β_all)) / threshold, 1.0)
            alive &= self._random(2 * n, depth) < p
            β_all = β_all / dr.select(p > 0.0, p, 1.0)
        keep = dr.compress(alive)
        if dr.width(keep) == 0:  # Dr.Jit 1.5 crashes on dr.select of empty arrays
            return rays.take(keep)
        lane = dr.gather(mi.UInt32, lane, keep)
        refracted = dr.gather(mi.Bool, refracted, keep)
        d = dr.select(refracted, dr.gather(mi.Vector3f, d_t, lane), dr.gather(mi.Vector3f, d_r, lane))
        o = _offset(dr.gather(mi.Point3f, hit.p, lane), dr.gather(type(hit.n), hit.n, lane), d)
        region = dr.select(refracted, dr.gather(mi.UInt32, region_t, lane), dr.gather(mi.UInt32, rays.region, lane))
        return _Rays(o=o, d=d, β=dr.gather(mi.Color3f, β_all, keep),
                     camera=dr.gather(mi.UInt32, rays.camera, lane), region=region)

    # ------------------------------------------------------------ the scene
    def bind(self, scene: mi.Scene) -> Surroundings:
        """The surroundings of ``scene`` (container, IOR, light, backdrop), checked and built once
        per scene (its shapes identify it); their parameters then appear in ``mi.traverse``."""
        key = (*scene.shapes(), scene.environment())
        if self._bound is None or len(self._bound[0]) != len(key) or \
                any(a is not b for a, b in zip(self._bound[0], key)):
            self._bound = (key, surroundings_of(scene, self.model.render, self.refine))
        return self._bound[1]

    def frame_of(self, scene: mi.Scene) -> FieldFrame:
        """The field's frame bounded by the scene's container (by the unit sphere without one)."""
        bbox = shapes_bbox(scene_parts(scene)[0])
        bounds = (tuple(bbox.min), tuple(bbox.max)) if bbox.valid() else None
        return dataclasses.replace(self.frame, bounds=bounds)


@dataclass
class _Rays:
    """A generation of the ray tree: one lane per live ray."""
    o: mi.Point3f
    d: mi.Vector3f
    β: mi.Color3f
    camera: mi.UInt32
    region: mi.UInt32
    """Where the ray is: 0 the world, g + 1 inside interface g (:mod:`reneus_mi.render.interfaces`)."""

    @property
    def size(self) -> int:
        return dr.width(self.camera)

    def take(self, index: mi.UInt32) -> '_Rays':
        return _Rays(o=dr.gather(mi.Point3f, self.o, index), d=dr.gather(mi.Vector3f, self.d, index),
                     β=dr.gather(mi.Color3f, self.β, index), camera=dr.gather(mi.UInt32, self.camera, index),
                     region=dr.gather(mi.UInt32, self.region, index))


class _Accumulator:
    """Per camera ray sums, filled by scatter-adds from every generation."""

    def __init__(self, n: int):
        self.L = dr.zeros(mi.Color3f, n)
        self.mask = dr.zeros(mi.Bool, n)
        self.sparsity = dr.zeros(mi.Float, n)
        self.eikonal = dr.zeros(mi.Float, n)
        self.n_samples = dr.zeros(mi.Float, n)
        self.normal = dr.zeros(mi.Vector3f, n)
        self.nearest = dr.zeros(mi.Float, n)
        self.nearest_color = dr.zeros(mi.Color3f, n)
        self.near_edge = dr.zeros(mi.Bool, n)

    def mark_container(self, camera, hit):
        dr.scatter(self.mask, hit, camera)

    def mark_edge(self, camera, near):
        dr.scatter(self.near_edge, True, camera, near)

    def add(self, camera, value, active):
        dr.scatter_add(self.L, value, camera, active)

    def add_segment(self, camera, β: mi.Color3f, vr):
        """A volume-rendered segment's loss terms, its path's weight ``β`` applied where they sum as L does."""
        opacity = 1.0 - vr.transmittance
        dr.scatter_add(self.normal, _mean(β) * vr.normal, camera)
        dr.scatter_add(self.sparsity, opacity, camera)
        dr.scatter_add(self.eikonal, vr.eikonal, camera)
        dr.scatter_add(self.n_samples, mi.Float(vr.n_samples) + 0.0 * opacity, camera)
        misses = dr.detach(vr.nearest) > 0.0
        dr.scatter_add(self.nearest, _mean(dr.detach(β)) * vr.nearest, camera, misses)
        dr.scatter_add(self.nearest_color, dr.detach(β) * vr.nearest_color, camera, misses)

    def result(self) -> mi.Color3f:
        # The sums are scatter targets: handed on unevaluated, a later kernel
        # (the film's splat) meets them dirty and Dr.Jit aborts.
        dr.eval(self.L, self.mask, self.sparsity, self.eikonal, self.n_samples, self.normal, self.nearest,
                self.nearest_color)
        return self.L


@dataclass
class _Hit:
    """Where rays meet the container: distance, point, geometric and shading normals (world)."""
    t: mi.Float
    p: mi.Point3f
    n: mi.Vector3f
    n_s: mi.Vector3f
    valid: mi.Bool
    group: mi.UInt32
    """The interface met."""
    si: mi.SurfaceInteraction3f
    """Mitsuba's intersection (in the container's frame): the shape and triangle met."""


def _peak(β: mi.Color3f) -> mi.Float:
    """A branch's largest channel: what decides whether it is followed."""
    return dr.maximum(dr.maximum(β.x, β.y), β.z)


def _mean(β: mi.Color3f) -> mi.Float:
    return (β.x + β.y + β.z) / 3.0


def _offset(p: mi.Point3f, n: mi.Vector3f, d: mi.Vector3f) -> mi.Point3f:
    """The origin of a ray leaving ``p`` along ``d``: nudged off the surface to the side ``d``
    goes, by Mitsuba's spawn_ray offset. Unlike spawn_ray it keeps the derivative of ``p``
    (the glass's pose moves the next ray's origin)."""
    q = dr.detach(p)
    size = 1.0 + dr.maximum(dr.maximum(dr.abs(q.x), dr.abs(q.y)), dr.abs(q.z))
    return mi.Point3f(p + dr.detach(dr.mulsign(mi.Vector3f(n), dr.dot(n, d)) * (size * mi.math.RayEpsilon)))


mi.register_integrator('reneus', lambda props: ReNeuSIntegrator(props))
