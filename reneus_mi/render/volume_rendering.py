"""Volume rendering of ray segments inside the container (NeuS's ``render_core``).

The integrator traces camera rays through the glass and hands every segment that
lies inside the container to :func:`volume_render`, in the field's frame. The
segment is sampled hierarchically by the integrator's sampler
(:mod:`reneus_mi.render.ray_samplers`), after its occupancy grid, if it has one, has
clipped the segment to where the surface can be; the samples and
the segment's ends bound S - 1 sections that tile [t_near, t_far]. Each section
is evaluated once, at its midpoint: SDF g, gradient ∇g, feature and radiance c.
As NeuS, the SDF at the section's ends is extrapolated with the (annealed)
cosine between ray and gradient, and the section's opacity is the unbiased,
occlusion-aware

    α_i = clip((Φ_s(g_prev) - Φ_s(g_next) + 1e-5) / (Φ_s(g_prev) + 1e-5), 0, 1),

with w_i = α_i Π_{j<i} (1 - α_j). The segment returns Σ w_i c_i and the
residual transmittance Π (1 - α_i), which scales what lies beyond ``t_far``
(ReNeuS Eq. 12, and the sparsity prior L_trans).

Gradients reach the field's parameters through g, ∇g (a first-order finite
difference, see :class:`reneus_mi.fields.base.Field`), c and s, never through the
sample positions.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from reneus_mi.render.ray_samplers import NeuSSampler, composite, neus_alpha, segment_layout
from reneus_mi.utils.errors import ReneusError


@dataclass
class VolumeResult:
    """What a batch of R segments contributes; every array has R entries."""

    color: mi.Color3f
    """Σ_i w_i c_i over the segment (linear radiance)."""
    transmittance: mi.Float
    """Π_i (1 - α_i): the fraction of the light from beyond ``t_far`` that reaches ``o``."""
    depth: mi.Float
    """Σ_i w_i t_i, t_i the section midpoints (not normalised by Σ w_i)."""
    normal: mi.Vector3f
    """Σ_i w_i n_i, n_i the normalised SDF gradient (not normalised)."""
    eikonal: mi.Float
    """Σ_i (|∇g(x_i)| - 1)² over the segment's sections (a sum, not a mean)."""
    n_samples: mi.UInt32
    """Sections (field evaluations) per segment, to turn ``eikonal`` into a mean
    (0 for a segment that the occupancy grid skipped)."""
    nearest: mi.Float
    """The SDF g at the segment's section of least g, with its gradient in the field's parameters
    only (not through where the section lies): where the segment passes nearest the surface, and
    where a part the field has not grown yet would have to begin (0 for a segment that the
    occupancy grid skipped)."""
    nearest_color: mi.Color3f
    """The radiance c at that section (no gradient): what the segment would bring if it ended there."""


def _check_widths(**arrays) -> int:
    widths = {name: dr.width(a) for name, a in arrays.items() if a is not None}
    n_rays = widths['o']
    wrong = {name: w for name, w in widths.items() if w != n_rays}
    if wrong:
        raise ReneusError(f'volume_render: every input needs one entry per segment ({n_rays}, as o), '
                         f'got widths {wrong}')
    return n_rays


def volume_render(field, sampler: NeuSSampler, o: mi.Point3f, d: mi.Vector3f, t_near: mi.Float,
                  t_far: mi.Float, *, jitter: mi.Float | None = None, cos_anneal_ratio: float = 1.0,
                  sigma_a: mi.Color3f | None = None) -> VolumeResult:
    """Volume render the segments ``o + t d``, ``t ∈ [t_near, t_far]``, through ``field``.

    ``sampler`` places the samples (``SamplerConfig(...).setup()``). ``d`` must be
    unit length. ``jitter`` (one value in [0, 1) per segment, or None for the
    stratum midpoints) offsets the coarse samples during training.
    ``cos_anneal_ratio`` (a float, or an opaque ``mi.Float`` that changes without recompiling)
    is NeuS's: 0 uses the smoothed cosine (1 - cos)/2 early in
    training, 1 the true cosine. A segment with ``t_far <= t_near`` contributes
    nothing (transmittance 1), so callers can mask lanes that way; so does one
    that the sampler's occupancy grid finds empty, at no field evaluation.
    ``sigma_a`` (RGB, per unit of ``t``, one for all segments or one each; None: none) is the
    absorption of the medium the field lies in: the light of a section at ``t`` reaches ``o`` times exp(-sigma_a t)
    (Beer-Lambert, from ``o``); the light from beyond ``t_far`` is the caller's to attenuate.
    """
    if isinstance(cos_anneal_ratio, (int, float)) and not 0.0 <= cos_anneal_ratio <= 1.0:
        raise ReneusError(f'volume_render: cos_anneal_ratio={cos_anneal_ratio!r}, expected a value in [0, 1]')
    n_rays = _check_widths(o=o, d=d, t_near=t_near, t_far=t_far, jitter=jitter)
    if n_rays == 0:
        return _render(field, sampler, o, d, t_near, t_far, jitter, cos_anneal_ratio, sigma_a)
    segments = sampler.clip(field, o, d, t_near, t_far)
    keep = segments.index
    if keep is None:
        return _render(field, sampler, o, d, t_near, t_far, jitter, cos_anneal_ratio, sigma_a)
    n_kept = dr.width(keep)
    r = _render(field, sampler, dr.gather(mi.Point3f, o, keep), dr.gather(mi.Vector3f, d, keep),
                segments.t_near, segments.t_far, None if jitter is None else dr.gather(mi.Float, jitter, keep),
                cos_anneal_ratio, _per_segment(sigma_a, lambda σ: dr.gather(mi.Color3f, σ, keep)))
    if n_kept == n_rays:
        return r

    def spread(cls, value, fill):
        full = dr.full(cls, fill, n_rays)
        if n_kept:
            dr.scatter(full, value, keep)
        return full

    return VolumeResult(color=spread(mi.Color3f, r.color, 0.0), transmittance=spread(mi.Float, r.transmittance, 1.0),
                        depth=spread(mi.Float, r.depth, 0.0), normal=spread(mi.Vector3f, r.normal, 0.0),
                        eikonal=spread(mi.Float, r.eikonal, 0.0), n_samples=spread(mi.UInt32, r.n_samples, 0),
                        nearest=spread(mi.Float, r.nearest, 0.0), nearest_color=spread(mi.Color3f, r.nearest_color, 0.0))


def _per_segment(sigma_a, spread):
    """``sigma_a`` spread as its segments are (``spread``) where it holds one per segment."""
    return sigma_a if sigma_a is None or dr.width(sigma_a) == 1 else spread(sigma_a)


def _stretch(t: mi.Float, t_near: mi.Float, t_far: mi.Float, n: int) -> mi.Float:
    """Sample positions as fixed fractions of their segment (``n`` per segment): the same
    values, but they follow the segment's ends when these move (the glass's IOR and pose
    move where segments end)."""
    near, far = dr.repeat(t_near, n), dr.repeat(t_far, n)
    if not (dr.grad_enabled(near) or dr.grad_enabled(far)):
        return t
    length = dr.detach(far) - dr.detach(near)
    u = dr.select(length > 0.0, (t - dr.detach(near)) / length, 0.0)
    return dr.replace_grad(t, near + u * (far - near))


def _render(field, sampler, o, d, t_near, t_far, jitter, cos_anneal_ratio, sigma_a) -> VolumeResult:
    """:func:`volume_render` of segments that all need sampling."""
    n_rays = dr.width(o)
    n = sampler.config.n_coarse + sampler.config.n_fine + 1
    if n_rays == 0:
        return VolumeResult(dr.zeros(mi.Color3f, 0), dr.zeros(mi.Float, 0), dr.zeros(mi.Float, 0),
                            dr.zeros(mi.Vector3f, 0), dr.zeros(mi.Float, 0), dr.zeros(mi.UInt32, 0),
                            dr.zeros(mi.Float, 0), dr.zeros(mi.Color3f, 0))

    t, n_t = sampler.sample(field, o, d, t_near, t_far, jitter)
    ray, i = segment_layout(n_rays, n)
    lo = _stretch(dr.gather(mi.Float, t, ray * n_t + i), t_near, t_far, n)
    hi = _stretch(dr.gather(mi.Float, t, ray * n_t + i + 1), t_near, t_far, n)
    dist = hi - lo
    t_mid = 0.5 * (lo + hi)
    # repeat, not a gather by ray: its reverse mode is a block sum, no atomics.
    d_s = dr.repeat(d, n)
    x = dr.repeat(o, n) + d_s * t_mid

    sdf, grad, feature = field.gradient(x)
    # The floor keeps normalisation and |∇g| differentiable where ∇g vanishes.
    grad_norm = dr.sqrt(dr.maximum(dr.squared_norm(grad), 1e-12))
    normal = grad / grad_norm

    # NeuS's cosine annealing: early on, (1 - cos)/2 lets sections facing away from
    # the ray (cos > 0) keep some opacity, so gradients reach the back of surfaces.
    true_cos = dr.dot(d_s, grad)
    iter_cos = -(dr.maximum(0.5 - 0.5 * true_cos, 0.0) * (1.0 - cos_anneal_ratio)
                 + dr.maximum(-true_cos, 0.0) * cos_anneal_ratio)
    half = iter_cos * dist * 0.5
    alpha = neus_alpha(sdf - half, sdf + half, field.inv_s())
    # A section of zero length has no extent to absorb in, whatever NeuS's ε says.
    alpha = dr.select(dist > 0.0, alpha, 0.0)
    color = field.radiance(x, d_s, normal, feature)
    if sigma_a is not None:
        color *= dr.exp(-_per_segment(sigma_a, lambda σ: dr.repeat(σ, n)) * t_mid)
    eikonal = dr.square(grad_norm - 1.0)
    # One kernel for both networks: each block reduction below evaluates its
    # input, and would otherwise re-run the networks behind it.
    dr.eval(alpha, color, normal, eikonal, sdf)

    weights, transmittance = composite(alpha, n)
    g = dr.detach(sdf)
    at_nearest = dr.select(g <= dr.repeat(dr.block_reduce(dr.ReduceOp.Min, g, n), n), 1.0, 0.0)
    # The reach term moves the field, not the rays: where the glass is refined the sections move
    # with it, and g's derivative along that motion (∇g · dx) is taken out, to first order.
    g_field = sdf - dr.dot(dr.detach(grad), x - dr.detach(x)) if dr.grad_enabled(x) else sdf
    color_sum, depth, normal, eikonal, nearest, nearest_color, ties = dr.block_sum(
        (color * weights, t_mid * weights, normal * weights, eikonal, g_field * at_nearest,
         dr.detach(color) * at_nearest, at_nearest), n)
    return VolumeResult(color=color_sum, transmittance=transmittance, depth=depth, normal=normal,
                        eikonal=eikonal, n_samples=dr.full(mi.UInt32, n, n_rays),
                        nearest=nearest / ties, nearest_color=nearest_color / ties)
