"""The ``reneus`` integrator: ReNeuS's hybrid renderer (Sec. 3.3 of the paper)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from reneus_mi.fields import FIELD_KINDS, Field, load_field
from reneus_mi.optics import interface
from reneus_mi.ray_samplers import SamplerConfig
from reneus_mi.volume_rendering import volume_render

VARIANT = mi.variant()

MODES = ('reneus', 'neus', 'neus_plus')

#: Parameters that configure the integrator's sampler (:class:`SamplerConfig`'s fields).
_SAMPLER_PARAMETERS = tuple(f.name for f in dataclasses.fields(SamplerConfig))
#: Integrator parameters other than ``field_*`` constructor arguments.
_PARAMETERS = ('mode', 'max_depth', 'terminal', 'rr_depth', 'gamma', 'aovs', 'field', 'field_center',
               'field_scale', 'dataset') + _SAMPLER_PARAMETERS

#: Names of the AOV channels, after R, G, B (and alpha where the film has it).
AOV_NAMES = ('mask', 'sparsity', 'nx', 'ny', 'nz')


@dataclass
class TraceResult:
    """What :meth:`ReNeuSIntegrator.trace` returns per camera ray."""
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


class ReNeuSIntegrator(mi.ad.integrators.common.ADIntegrator):
    r"""
    ReNeuS's hybrid renderer: ray tracing through a transparent container,
    NeuS volume rendering inside it.

    The scene's shapes must all carry a smooth ``dielectric`` BSDF: together
    they are the container, and its IOR is the BSDF's η. The scene's
    environment emitter (usually ``constant``, 0.8 in the paper) is the ambient
    light C_out. Inside the container lives a field (:mod:`reneus_mi.fields`):
    an SDF with a radiance, rendered with NeuS's unbiased weights.

    Each camera ray is traced: at every interface hit both the reflected and
    the refracted ray are followed, weighted by the unpolarised Fresnel
    reflectance R and by 1 - R (total internal reflection gives R = 1). A ray
    segment inside the container is volume rendered; its transmittance T_ℓ
    multiplies whatever lies beyond it. A ray that leaves takes the ambient.

    **Depth.** ``max_depth`` = D_re counts interface events. A ray created by
    the D-th event is still followed to the next surface: if it escapes it
    takes the ambient, if it is inside its segment is volume rendered. What
    lies beyond the surface that ends it is ``terminal``: with ``ambient`` (the
    default) the ambient radiance, attenuated by the segment's transmittance;
    with ``black`` nothing, which is what Mitsuba's ``path`` integrator
    computes with ``max_depth = D_re + 1``. In ambient light a non-absorbing
    container is filled with nearly the ambient radiance, so ``ambient`` is
    the far better truncation: with ``black`` the field has to explain the
    light of the dropped paths, and paints fake walls to do so. D_re = 0
    renders the camera ray's own segment only.

    **Radiance units.** As in the paper, the field's colour is seen through an
    interface with weight 1 - R only: the η² radiance scaling at a refractive
    interface is folded into the field's colour (a path tracer sees an emitter
    of radiance c·η² inside the glass as this integrator sees colour c).

    .. pluginparameters::

     * - mode
       - |string|
       - ``reneus`` (the paper), ``neus`` (ignores the container: plain NeuS in
         the field's bounding sphere) or ``neus_plus`` (refracts once on entry,
         no reflection, no Fresnel weights). (Default: ``reneus``)
     * - max_depth
       - |int|
       - D_re, the number of interface events followed (see above). (Default: 2)
     * - terminal
       - |string|
       - What a ray left at the depth limit sees beyond its last segment:
         ``ambient`` or ``black`` (see above). (Default: ``ambient``)
     * - n_coarse, n_fine, n_upsample_steps, upsample_s
       - |int|, |float|
       - NeuS's hierarchical sampling of each inside segment: coarse
         (stratified) samples, importance samples added in ``n_upsample_steps``
         rounds, the fixed sharpness of the first round (doubled each round).
         (Defaults: :class:`reneus_mi.ray_samplers.SamplerConfig`)
     * - occupancy_resolution, occupancy_lipschitz, occupancy_margin, occupancy_update_every
       - |int|, |float|
       - Empty-space skipping: an occupancy grid of the SDF with
         ``occupancy_resolution``^3 cells clips every inside segment to where
         the surface can be (0 turns it off). (Defaults:
         :class:`reneus_mi.ray_samplers.SamplerConfig`)
     * - gamma
       - |float|
       - Output is C^(1/gamma) (the paper's camera response); 1 gives linear
         radiance. (Default: 2.2)
     * - aovs
       - |bool|
       - Append the AOV channels ``mask`` (camera ray meets the container),
         ``sparsity`` (Σ 1 - T_ℓ over inside segments) and ``nx, ny, nz``
         (accumulated normals) to the image. (Default: false)
     * - field
       - |string|
       - ``neus`` (an untrained NeuS field), ``sphere``, ``box``, ``torus``
         (analytic fields), or the path of a field saved with
         ``Field.save``/a checkpoint. Properties named ``field_<arg>`` are
         passed to the field's constructor as ``<arg>``. (Default: ``neus``)
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

    The field's parameters appear in ``mi.traverse(scene)`` under the
    integrator's id (e.g. ``field.sdf.weights``); ``mi.render(scene,
    params=params)`` differentiates with respect to them.
    """

    def __init__(self, props: mi.Properties):
        mode = props.get('mode', 'reneus')
        if mode not in MODES:
            raise ValueError(f"reneus integrator: mode={mode!r}; expected one of {', '.join(MODES)}")
        max_depth = props.get('max_depth', 2)
        if max_depth < 0:
            raise ValueError(f'reneus integrator: max_depth={max_depth}; expected an integer >= 0 '
                             '(D_re, the number of interface events followed)')
        super().__init__(props)
        self.mode = mode
        self.max_depth = max_depth
        self.terminal = props.get('terminal', 'ambient')
        if self.terminal not in ('ambient', 'black'):
            raise ValueError(f"reneus integrator: terminal={self.terminal!r}; expected 'ambient' or 'black'")
        try:
            self.sampler = SamplerConfig(**{name: props.get(name) for name in _SAMPLER_PARAMETERS
                                            if name in props}).setup()
        except ValueError as e:
            raise ValueError(f'reneus integrator: {e}') from None
        self.gamma = float(props.get('gamma', 2.2))
        if self.gamma <= 0:
            raise ValueError(f'reneus integrator: gamma={self.gamma}; expected > 0 (1 = linear output)')
        self.aovs_enabled = bool(props.get('aovs', False))
        self.dataset = props.get('dataset', '')
        center = props.get('field_center', mi.ScalarPoint3f(0.0))
        self.field_center = tuple(float(c) for c in center)
        self.field_scale = float(props.get('field_scale', 1.0))
        if self.field_scale <= 0:
            raise ValueError(f'reneus integrator: field_scale={self.field_scale}; expected > 0')
        self.field = _make_field(props)
        unknown = [n for n in props.unqueried() if n not in _PARAMETERS]
        if unknown:
            raise ValueError(f"reneus integrator: unknown parameter(s) {', '.join(map(repr, unknown))}; "
                             f"expected {', '.join(_PARAMETERS)} or field_<constructor argument>")

    # ------------------------------------------------------------ Mitsuba API
    def aov_names(self):
        return list(AOV_NAMES) if self.aovs_enabled else []

    @property
    def field(self) -> Field:
        return self._field

    @field.setter
    def field(self, value: Field) -> None:
        self._field = value
        # mi.traverse gets copies: SceneParameters rebinds the arrays it is
        # given, while a packed network reads its weights through views of
        # its own buffer, so new values must be written into the field.
        self._exposed = {key: type(v)(v) for key, v in value.params().items()}
        self._exposed_changed = False

    def traverse(self, cb):
        for key, value in self._exposed.items():
            cb.put(key, value, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        # Written in sample(), not here: SceneParameters.update() evaluates
        # the scene afterwards, which cuts the autodiff link of the write.
        self._exposed_changed |= any(k in self._exposed for k in keys)

    def to_string(self):
        return (f'ReNeuSIntegrator[mode={self.mode}, max_depth={self.max_depth}, terminal={self.terminal}, '
                f'samples={self.sampler.config.n_coarse}+{self.sampler.config.n_fine}, '
                f'field={type(self.field).__name__}]')

    def sample(self, mode, scene, sampler, ray, δL=None, state_in=None, active=True, **kwargs):
        if self._exposed_changed:
            self._field.set_params(self._exposed)
        result = self.trace(scene, mi.Ray3f(ray), active=active)
        L = self.tonemap(result.L)
        aovs = []
        if self.aovs_enabled:
            n = result.normal
            aovs = [mi.Float(result.mask), result.sparsity, n.x, n.y, n.z]
        return dr.select(active, L, 0.0), active, aovs, None

    # ------------------------------------------------------------ the method
    def tonemap(self, L: mi.Color3f) -> mi.Color3f:
        """The paper's 𝒢(C) = C^(1/γ); the clamp keeps its derivative finite at 0."""
        if self.gamma == 1.0:
            return L
        return dr.power(dr.maximum(L, 1e-6), 1.0 / self.gamma)

    def trace(self, scene: mi.Scene, ray: mi.Ray3f, *, jitter: mi.Float | None = None,
              cos_anneal_ratio: float = 1.0, active: mi.Bool | bool = True) -> TraceResult:
        """Render camera rays (world space) into linear radiance and loss terms.

        ``jitter`` (one value in [0, 1) per camera ray) shifts the stratified
        samples of every segment the ray spawns; ``None`` takes midpoints.
        """
        eta = self._container_eta(scene)
        n = dr.width(ray.o)
        acc = _Accumulator(n)
        camera = dr.arange(mi.UInt32, n)
        rays = _Rays(o=mi.Point3f(ray.o), d=mi.Vector3f(ray.d), β=dr.ones(mi.Float, n), camera=camera)
        rays = rays.take(dr.compress(dr.full(mi.Bool, True, n) & active))
        if self.mode == 'neus':
            self._trace_neus(scene, rays, acc, jitter, cos_anneal_ratio)
        else:
            self._trace_container(scene, eta, rays, acc, jitter, cos_anneal_ratio)
        return acc.result()

    # One generation of the ray tree per loop turn: rays are compressed to the
    # live ones so that the 2^k growth costs nothing for rays that escaped.
    def _trace_container(self, scene, eta, rays, acc, jitter, cos_anneal_ratio):
        plus = self.mode == 'neus_plus'
        depth_limit = 1 if plus else self.max_depth
        for depth in range(depth_limit + 1):
            if rays.size == 0:
                return
            si = scene.ray_intersect(mi.Ray3f(rays.o, rays.d))
            hit = si.is_valid()
            if depth == 0:
                acc.mark_container(rays.camera, hit)
            leaving = hit & (dr.dot(rays.d, si.n) > 0)
            acc.add(rays.camera, rays.β * _ambient(scene, rays.d), ~hit)
            T = self._render_inside(rays, si.t, leaving, acc, jitter, cos_anneal_ratio)
            if plus and depth == 1:
                # NeuS+: the light beyond the segment arrives straight, unrefracted.
                acc.add(rays.camera, rays.β * T * _ambient(scene, rays.d), leaving)
                return
            if depth == depth_limit:
                if self.terminal == 'ambient':
                    acc.add(rays.camera, rays.β * T * _ambient(scene, rays.d), hit)
                return
            rays = self._interface(rays, si, hit, T, eta, reflect=not plus)

    def _trace_neus(self, scene, rays, acc, jitter, cos_anneal_ratio):
        # Plain NeuS: the field's unit bounding sphere, ambient beyond it.
        c, r = mi.Point3f(*self.field_center), self.field_scale
        o = (rays.o - c) / r
        b = dr.dot(o, rays.d)
        disc = b * b - (dr.squared_norm(o) - 1.0)
        t_far = -b + dr.safe_sqrt(disc)
        inside = (disc > 0) & (t_far > 0)
        acc.mark_container(rays.camera, inside)
        t_near = dr.maximum(-b - dr.safe_sqrt(disc), 0.0)
        rays.o = mi.Point3f(rays.o + rays.d * (t_near * r))
        T = self._render_inside(rays, (t_far - t_near) * r, inside, acc, jitter, cos_anneal_ratio)
        acc.add(rays.camera, rays.β * T * _ambient(scene, rays.d), mi.Bool(True))

    def _render_inside(self, rays, t_far, inside, acc, jitter, cos_anneal_ratio) -> mi.Float:
        """Volume render the rays' segments [0, t_far] where ``inside``; return T (1 elsewhere)."""
        T = dr.ones(mi.Float, rays.size)
        seg = dr.compress(inside)
        if dr.width(seg) == 0:
            return T
        s = rays.take(seg)
        t = dr.gather(mi.Float, t_far, seg)
        r = self.field_scale
        o_field = (s.o - mi.Point3f(*self.field_center)) / r
        u = None if jitter is None else dr.gather(mi.Float, jitter, s.camera)
        vr = volume_render(self.field, self.sampler, o_field, s.d, dr.zeros(mi.Float, dr.width(seg)), t / r,
                           jitter=u, cos_anneal_ratio=cos_anneal_ratio)
        acc.add(s.camera, s.β * vr.color, mi.Bool(True))
        acc.add_segment(s.camera, s.β * vr.normal, 1.0 - vr.transmittance, vr.eikonal, vr.n_samples)
        dr.scatter(T, vr.transmittance, seg)
        return T

    def _interface(self, rays, si, hit, T, eta, reflect: bool):
        """Spawn the next generation: reflected (β·T·R) and refracted (β·T·(1-R)) rays."""
        R, d_r, d_t = interface(rays.d, si.n, eta)
        β = rays.β * T
        if reflect:
            β_r, β_t = β * R, β * (1.0 - R)
        else:
            β_r, β_t = dr.zeros(mi.Float, rays.size), dr.select(R < 1.0, β, 0.0)
        # Candidates 0..n-1 are the reflected rays, n..2n-1 the refracted ones.
        n = rays.size
        j = dr.arange(mi.UInt32, 2 * n)
        refracted = j >= n
        lane = dr.select(refracted, j - n, j)
        β_all = dr.select(refracted, dr.gather(mi.Float, β_t, lane), dr.gather(mi.Float, β_r, lane))
        keep = dr.compress(dr.gather(mi.Bool, hit, lane) & (dr.detach(β_all) > 0.0))
        if dr.width(keep) == 0:  # Dr.Jit 1.5 crashes on dr.select of empty arrays
            return rays.take(keep)
        lane = dr.gather(mi.UInt32, lane, keep)
        refracted = dr.gather(mi.Bool, refracted, keep)
        d = dr.select(refracted, dr.gather(mi.Vector3f, d_t, lane), dr.gather(mi.Vector3f, d_r, lane))
        si_k = dr.gather(mi.SurfaceInteraction3f, si, lane)
        return _Rays(o=si_k.spawn_ray(d).o, d=d, β=dr.gather(mi.Float, β_all, keep),
                     camera=dr.gather(mi.UInt32, rays.camera, lane))

    def _container_eta(self, scene: mi.Scene) -> mi.Float:
        """The container's relative IOR η; checks that every shape is a smooth dielectric."""
        shapes = scene.shapes()
        if self.mode == 'neus':
            return mi.Float(1.0)
        if not shapes:
            raise ValueError('reneus integrator: the scene has no shape; expected the container '
                             'as a shape with a dielectric BSDF')
        eta = None
        for shape in shapes:
            bsdf = shape.bsdf()
            name = bsdf.class_name() if bsdf is not None else 'none'
            if name != 'SmoothDielectric':
                raise ValueError(f"reneus integrator: shape '{shape.id()}' has a {name} BSDF; every "
                                 "shape must be the container, with a smooth 'dielectric' BSDF")
            value = mi.traverse(bsdf)['eta']
            if eta is not None and dr.any(dr.abs(value - eta) > 1e-6):
                raise ValueError(f"reneus integrator: shape '{shape.id()}' has IOR {value} but another "
                                 f'container shape has {eta}; expected one IOR')
            eta = value
        if scene.environment() is None:
            raise ValueError("reneus integrator: the scene has no environment emitter; expected "
                             "<emitter type=\"constant\"> with the ambient radiance C_out (0.8 in the paper)")
        return mi.Float(eta)


@dataclass
class _Rays:
    """A generation of the ray tree: one lane per live ray."""
    o: mi.Point3f
    d: mi.Vector3f
    β: mi.Float
    camera: mi.UInt32

    @property
    def size(self) -> int:
        return dr.width(self.camera)

    def take(self, index: mi.UInt32) -> '_Rays':
        return _Rays(o=dr.gather(mi.Point3f, self.o, index), d=dr.gather(mi.Vector3f, self.d, index),
                     β=dr.gather(mi.Float, self.β, index), camera=dr.gather(mi.UInt32, self.camera, index))


class _Accumulator:
    """Per camera ray sums, filled by scatter-adds from every generation."""

    def __init__(self, n: int):
        self.L = dr.zeros(mi.Color3f, n)
        self.mask = dr.zeros(mi.Bool, n)
        self.sparsity = dr.zeros(mi.Float, n)
        self.eikonal = dr.zeros(mi.Float, n)
        self.n_samples = dr.zeros(mi.Float, n)
        self.normal = dr.zeros(mi.Vector3f, n)

    def mark_container(self, camera, hit):
        dr.scatter(self.mask, hit, camera)

    def add(self, camera, value, active):
        dr.scatter_add(self.L, value, camera, active)

    def add_segment(self, camera, normal, opacity, eikonal, n_samples):
        dr.scatter_add(self.normal, normal, camera)
        dr.scatter_add(self.sparsity, opacity, camera)
        dr.scatter_add(self.eikonal, eikonal, camera)
        dr.scatter_add(self.n_samples, mi.Float(n_samples) + 0.0 * opacity, camera)

    def result(self) -> TraceResult:
        # The sums are scatter targets: handed on unevaluated, a later kernel
        # (the film's splat) meets them dirty and Dr.Jit aborts.
        dr.eval(self.L, self.mask, self.sparsity, self.eikonal, self.n_samples, self.normal)
        return TraceResult(L=self.L, mask=self.mask, sparsity=self.sparsity, eikonal=self.eikonal,
                           n_samples=self.n_samples, normal=self.normal)


def _ambient(scene: mi.Scene, d: mi.Vector3f) -> mi.Color3f:
    """Radiance of the environment seen along ``d`` (C_out)."""
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(d))
    si.wi = -d
    return scene.environment().eval(si)


def _make_field(props) -> Field:
    """Build the field named by ``field`` with the ``field_<arg>`` properties."""
    spec = props.get('field', 'neus')
    kwargs = {}
    for name in props.keys():
        if name.startswith('field_') and name not in ('field_center', 'field_scale'):
            value = props.get(name)
            if not isinstance(value, (bool, int, float, str)):
                value = tuple(float(v) for v in value)
            kwargs[name[len('field_'):]] = value
    kinds = {cls.__name__.removesuffix('Field').lower(): cls for cls in FIELD_KINDS.values()}
    if spec in kinds:
        try:
            return kinds[spec](**kwargs)
        except TypeError as e:
            raise ValueError(f'reneus integrator: field={spec!r}: {e}') from None
    if spec.endswith('.npz'):
        if kwargs:
            raise ValueError(f'reneus integrator: field={spec!r} is a saved field; '
                             f"field_* parameters ({', '.join(kwargs)}) do not apply")
        return load_field(spec)
    raise ValueError(f"reneus integrator: field={spec!r}; expected one of {', '.join(sorted(kinds))} "
                     'or the path of a saved field (.npz)')
