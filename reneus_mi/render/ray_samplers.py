"""NeuS's hierarchical sampling of ray segments, as flat Dr.Jit arrays.

A batch of R segments ``o + t d``, ``t ∈ [t_near, t_far]``, is sampled with S
sorted values of ``t`` per segment, laid out as one flat array where entry
``ray * S + i`` is the i-th value of segment ``ray``. Per-segment products and
sums are block reductions of size S; nothing loops over rays in Python.

The scheme is NeuS's (Wang et al. 2021, ``up_sample``): stratified coarse
samples, then a few rounds that add samples by inverse-CDF sampling of the NeuS
weights computed with a fixed, growing sharpness, so that the samples gather
around the zero level set before the learned sharpness s is sharp enough to find
it. Sampling is not differentiated: gradients reach the field through the
rendered values at these positions (:mod:`reneus_mi.render.volume_rendering`), never
through the positions themselves.

Unlike NeuS, the sample set of a segment also holds ``t_near`` and ``t_far``, so
the sections between consecutive values tile the segment exactly and the
transmittance across it is the true residual that the integrator needs to
composite what lies beyond ``t_far``.

The sampler is a configured object, as nerfstudio's ray samplers:
:class:`SamplerConfig` holds the settings (each default written here only),
``SamplerConfig(...).setup()`` builds the :class:`NeuSSampler` that the
integrator owns. With ``occupancy_resolution > 0`` it keeps an
:class:`reneus_mi.render.occupancy.OccupancyGrid` of the field: segments are clipped to
the cells where the surface can be, and segments that cross none are skipped.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from reneus_mi.render.occupancy import OccupancyGrid
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.validate import check_numbers

#: Added to Φ_s in the α ratio, as in NeuS: it keeps α finite where Φ_s(prev) → 0.
ALPHA_EPS = 1e-5


def segment_layout(n_rays: int, n: int) -> tuple[mi.UInt32, mi.UInt32]:
    """Return ``(ray, i)`` for the flat layout of ``n`` entries per segment."""
    idx = dr.arange(mi.UInt32, n_rays * n)
    ray = idx // n
    return ray, idx - ray * n


def logistic_cdf(x: mi.Float, inv_s) -> mi.Float:
    """Φ_s(x) = 1 / (1 + exp(-s x)).

    The argument is clamped to ±40, where Φ_s is saturated in float32: this
    keeps exp() and the reverse pass finite for very sharp fields.
    """
    z = dr.clip(x * inv_s, -40.0, 40.0)
    return dr.rcp(1.0 + dr.exp(-z))


def neus_alpha(prev_sdf: mi.Float, next_sdf: mi.Float, inv_s) -> mi.Float:
    """NeuS's discrete opacity of a section from its (estimated) end SDF values.

    α = clip((Φ_s(prev) - Φ_s(next) + ε) / (Φ_s(prev) + ε), 0, 1), ε = 1e-5.
    """
    prev_cdf = logistic_cdf(prev_sdf, inv_s)
    next_cdf = logistic_cdf(next_sdf, inv_s)
    return dr.clip((prev_cdf - next_cdf + ALPHA_EPS) / (prev_cdf + ALPHA_EPS), 0.0, 1.0)


def composite(alpha: mi.Float, n: int) -> tuple[mi.Float, mi.Float]:
    """Weights w_i = α_i Π_{j<i}(1 - α_j) and the residual Π_i(1 - α_i) per segment.

    ``alpha`` holds ``n`` sections per segment. The product is the exponential of a
    prefix sum of logarithms, since ``block_prefix_reduce(Mul)`` has no reverse
    mode in Dr.Jit 1.5. 1 - α is floored at 1e-7 so that an opaque section gives
    a finite logarithm (and a zero gradient) rather than -inf.
    """
    log_t = dr.log(dr.maximum(1.0 - alpha, 1e-7))
    # Evaluated once: both block reductions below would otherwise recompute it.
    dr.eval(log_t)
    weights = alpha * dr.exp(dr.block_prefix_sum(log_t, n, exclusive=True))
    return weights, dr.exp(dr.block_sum(log_t, n))


def stratified_samples(t_near: mi.Float, t_far: mi.Float, n: int, jitter: mi.Float | None = None,
                       include_ends: bool = False) -> mi.Float:
    """``n`` stratified values of t per segment, sorted.

    Value i is ``t_near + (i + u) (t_far - t_near) / n`` with one offset ``u`` per
    segment: ``jitter`` (in [0, 1)) or 0.5 (the stratum midpoints) when None. With
    ``include_ends``, ``t_near`` and ``t_far`` frame them (n + 2 values per segment).
    """
    m = n + 2 if include_ends else n
    ray, i = segment_layout(dr.width(t_near), m)
    near = dr.gather(mi.Float, t_near, ray)
    far = dr.gather(mi.Float, t_far, ray)
    u = 0.5 if jitter is None else dr.gather(mi.Float, jitter, ray)
    k = mi.Float(i) - (1.0 if include_ends else 0.0)
    t = near + (far - near) * ((k + u) * (1.0 / n))
    if include_ends:
        t = dr.select(i == 0, near, dr.select(i == m - 1, far, t))
    return t


def importance_samples(t: mi.Float, weights: mi.Float, n_in: int, n_new: int) -> mi.Float:
    """``n_new`` sorted values per segment, drawn from the piecewise-constant pdf.

    ``t`` holds ``n_in`` sorted values per segment, ``weights`` the weight of the
    section that starts at each of them (the entry of the last value is ignored).
    As NeuS's ``sample_pdf``: 1e-5 is added to each weight so that empty segments
    still spread their samples, the quantiles are deterministic,
    u_j = (j + 1/2) / n_new, and t is linear in the CDF within a section.
    """
    n_rays = dr.width(t) // n_in
    _, i = segment_layout(n_rays, n_in)
    pdf = dr.select(i == n_in - 1, 0.0, weights + 1e-5)
    dr.eval(pdf)
    total = dr.repeat(dr.block_sum(pdf, n_in), n_in)
    # cdf[i] is the mass before value i: 0 at the first value, 1 at the last.
    cdf = dr.block_prefix_sum(pdf, n_in, exclusive=True) / total
    dr.eval(cdf)

    ray, j = segment_layout(n_rays, n_new)
    u = (mi.Float(j) + 0.5) * (1.0 / n_new)
    base = ray * n_in
    # First value whose cdf exceeds u (NeuS: searchsorted(..., right=True)).
    above = dr.binary_search(0, n_in - 1, lambda k: dr.gather(mi.Float, cdf, base + k) <= u)
    above = dr.maximum(above, 1)
    below = above - 1
    cdf_b = dr.gather(mi.Float, cdf, base + below)
    cdf_a = dr.gather(mi.Float, cdf, base + above)
    t_b = dr.gather(mi.Float, t, base + below)
    t_a = dr.gather(mi.Float, t, base + above)
    denom = cdf_a - cdf_b
    denom = dr.select(denom < 1e-5, 1.0, denom)
    return t_b + (u - cdf_b) / denom * (t_a - t_b)


def merge_ranks(a: mi.Float, n_a: int, b: mi.Float, n_b: int) -> tuple[mi.UInt32, mi.UInt32]:
    """Destinations of the entries of ``a`` and ``b`` in their per-segment merge.

    Both hold sorted values per segment (``n_a`` and ``n_b`` per segment). The
    rank of an element is its own index plus the number of smaller elements of
    the other list; ties go to ``a`` first, so every destination is distinct.
    Returned indices address the merged flat array of ``n_a + n_b`` per segment.
    """
    n_rays = dr.width(a) // n_a
    n = n_a + n_b

    def ranks(values, n_self, other, n_other, before):
        ray, i = segment_layout(n_rays, n_self)
        base = ray * n_other
        # The search may probe index n_other itself once it has converged: mask it.
        count = dr.binary_search(0, n_other, lambda k: before(
            dr.gather(mi.Float, other, base + k, k < n_other), values))
        return ray * n + i + count

    rank_a = ranks(a, n_a, b, n_b, lambda other, v: other < v)
    rank_b = ranks(b, n_b, a, n_a, lambda other, v: other <= v)
    return rank_a, rank_b


def merge_sorted(a: mi.Float, n_a: int, b: mi.Float, n_b: int) -> mi.Float:
    """Merge two arrays of per-segment sorted values into one (``n_a + n_b`` per segment)."""
    return scatter_merged(*merge_ranks(a, n_a, b, n_b), a, b)


def scatter_merged(rank_a: mi.UInt32, rank_b: mi.UInt32, x_a: mi.Float, x_b: mi.Float) -> mi.Float:
    """Place ``x_a`` and ``x_b`` (laid out like the lists given to :func:`merge_ranks`) in merged order."""
    merged = dr.zeros(mi.Float, dr.width(x_a) + dr.width(x_b))
    dr.scatter(merged, x_a, rank_a)
    dr.scatter(merged, x_b, rank_b)
    return merged


def upsample_weights(o: mi.Point3f, d: mi.Vector3f, t: mi.Float, sdf: mi.Float, n: int,
                     inv_s: float, bound: float) -> mi.Float:
    """NeuS weights of the sections between consecutive samples, at a fixed sharpness.

    The SDF is only known at the samples, so (as NeuS's ``up_sample``) the
    section's cosine is the SDF's finite difference along the ray, the smaller of
    it and the previous section's (robust next to the surface), clamped to
    [-1000, 0] and set to 0 outside the field's bounding sphere. The entry of the
    last value of each segment gets weight 0.
    """
    ray, i = segment_layout(dr.width(t) // n, n)
    idx = dr.arange(mi.UInt32, dr.width(t))
    first, last = i == 0, i == n - 1
    t_next = dr.gather(mi.Float, t, idx + 1, ~last)
    sdf_next = dr.gather(mi.Float, sdf, idx + 1, ~last)
    t_prev = dr.gather(mi.Float, t, idx - 1, ~first)
    sdf_prev = dr.gather(mi.Float, sdf, idx - 1, ~first)

    cos = (sdf_next - sdf) / (t_next - t + 1e-5)
    prev_cos = dr.select(first, 0.0, (sdf - sdf_prev) / (t - t_prev + 1e-5))
    cos = dr.clip(dr.minimum(cos, prev_cos), -1e3, 0.0)
    o_s = dr.gather(mi.Point3f, o, ray)
    d_s = dr.gather(mi.Vector3f, d, ray)
    inside = (dr.norm(o_s + d_s * t) < bound) | (dr.norm(o_s + d_s * t_next) < bound)
    cos = dr.select(inside, cos, 0.0)

    dist = t_next - t
    mid_sdf = 0.5 * (sdf + sdf_next)
    alpha = neus_alpha(mid_sdf - cos * dist * 0.5, mid_sdf + cos * dist * 0.5, inv_s)
    alpha = dr.select(last | (dist <= 0.0), 0.0, alpha)
    return composite(alpha, n)[0]


def _sdf_along(field, o: mi.Point3f, d: mi.Vector3f, t: mi.Float, n: int) -> mi.Float:
    """The SDF at ``o + t d`` for ``n`` values of t per segment, evaluated."""
    ray, _ = segment_layout(dr.width(o), n)
    x = dr.gather(mi.Point3f, o, ray) + dr.gather(mi.Vector3f, d, ray) * t
    # Evaluating x first keeps n out of the network's kernel, so one compilation
    # serves every round; t is evaluated too, as the merge reads it again.
    dr.eval(t, x)
    sdf = field.sdf(x)
    dr.eval(sdf)
    return sdf


@dataclass
class SamplerConfig:
    """How each inside segment is sampled (NeuS's hierarchical sampling, optionally an occupancy grid)."""

    n_coarse: int = 64
    """Coarse (stratified) samples per inside segment."""
    n_fine: int = 64
    """Importance samples per inside segment, added in ``n_upsample_steps`` rounds as in NeuS."""
    n_upsample_steps: int = 4
    """Rounds of NeuS's hierarchical up-sampling; must divide ``n_fine``."""
    upsample_s: float = 64.0
    """Fixed sharpness s of the first up-sampling round, doubled each round."""
    occupancy_resolution: int = 0
    """Cells per axis of the occupancy grid over the field's cube [-bound, bound]^3 (0: no grid).
    With a grid, segments are clipped to the cells where the surface can be and empty ones are
    skipped; 64 suits most objects."""
    occupancy_lipschitz: float = 2.0
    """Safety factor on the SDF's Lipschitz constant (|∇g| <= it): a cell is occupied when
    g(centre) <= factor x half the cell's diagonal + margin + the NeuS density band. 1 suffices for
    a true distance; a field in training is only near one."""
    occupancy_margin: float = 0.01
    """Extra distance (field units) by which a cell's centre SDF may exceed the Lipschitz bound and
    still count as occupied, for a grid a few steps stale. (The undershoot of NeuS's linearised
    section ends, factor x half the longest coarse section, is added to it.)"""
    occupancy_update_every: int = 16
    """Training steps between refreshes of the grid from the changing SDF (``NeuSSampler.update``)."""

    def __post_init__(self):
        check_numbers(self, positive=('n_coarse', 'n_upsample_steps', 'upsample_s', 'occupancy_lipschitz',
                                      'occupancy_update_every'),
                      at_least_zero=('n_fine', 'occupancy_resolution', 'occupancy_margin'))
        if self.n_fine % self.n_upsample_steps:
            raise ReneusError(f'sampling: n_fine={self.n_fine} is not a multiple of '
                              f'n_upsample_steps={self.n_upsample_steps}')

    def setup(self) -> 'NeuSSampler':
        return NeuSSampler(self)


@dataclass
class Segments:
    """The segments left to sample once the occupancy grid has clipped them."""

    index: mi.UInt32 | None
    """Which of the given segments cross an occupied cell (None: all of them, no grid)."""
    t_near: mi.Float
    """Start of each kept segment, moved up to its first occupied cell."""
    t_far: mi.Float
    """End of each kept segment, moved back to the end of its last occupied cell."""


class NeuSSampler:
    """NeuS's hierarchical sampler of ray segments, with an optional occupancy grid.

    One per integrator (``SamplerConfig(...).setup()``). The grid belongs to one
    field: it is built on first use, rebuilt when a different field comes, and
    refreshed by :meth:`update` as training changes the SDF.
    """

    def __init__(self, config: SamplerConfig):
        if config.occupancy_resolution:
            OccupancyGrid.check_size(config.occupancy_resolution)
        self.config = config
        self.grid: OccupancyGrid | None = None
        self._grid_field = None

    def update(self, field, step: int) -> None:
        """Refresh the occupancy grid from ``field`` every ``occupancy_update_every`` steps (else nothing)."""
        if self.config.occupancy_resolution and step % self.config.occupancy_update_every == 0:
            self._build(field)

    def _build(self, field) -> None:
        cfg = self.config
        # A coarse section is at most 2 bound / n_coarse long: NeuS's end values
        # g ± cos·Δ/2 undershoot g by up to L·Δ/2, which the margin must cover.
        slack = cfg.occupancy_lipschitz * field.bound / cfg.n_coarse
        self.grid = OccupancyGrid(cfg.occupancy_resolution, field.bound, lipschitz=cfg.occupancy_lipschitz,
                                  margin=cfg.occupancy_margin + slack)
        self.grid.update(field)
        self._grid_field = field

    def clip(self, field, o: mi.Point3f, d: mi.Vector3f, t_near: mi.Float, t_far: mi.Float) -> Segments:
        """Clip each segment to the span of occupied cells it crosses; drop those that cross none.

        Without a grid every segment is kept as it is (``index`` None).
        """
        if not self.config.occupancy_resolution:
            return Segments(None, t_near, t_far)
        if self._grid_field is not field:
            self._build(field)
        with dr.suspend_grad():
            first, last = self.grid.span(dr.detach(o), dr.detach(d), dr.detach(t_near), dr.detach(t_far))
            index = dr.compress(first < last)
            return Segments(index, dr.gather(mi.Float, first, index), dr.gather(mi.Float, last, index))

    def sample(self, field, o: mi.Point3f, d: mi.Vector3f, t_near: mi.Float, t_far: mi.Float,
               jitter: mi.Float | None = None) -> tuple[mi.Float, int]:
        """NeuS's hierarchical sampling of each segment; returns ``(t, S)``.

        ``t`` holds S = n_coarse + n_fine + 2 sorted values per segment, the first
        ``t_near`` and the last ``t_far``; it carries no gradient. ``jitter`` (one
        value in [0, 1) per segment, None for the stratum midpoints) offsets the
        coarse samples. Round k of the ``n_upsample_steps`` rounds adds
        ``n_fine / n_upsample_steps`` values drawn from the NeuS weights at
        sharpness ``upsample_s * 2**k``. The SDF is evaluated only at the new
        values of each round and merged along with them.
        """
        cfg = self.config
        with dr.suspend_grad():
            o, d = dr.detach(o), dr.detach(d)
            t = stratified_samples(dr.detach(t_near), dr.detach(t_far), cfg.n_coarse,
                                   None if jitter is None else dr.detach(jitter), include_ends=True)
            n = cfg.n_coarse + 2
            sdf = _sdf_along(field, o, d, t, n)
            n_step = cfg.n_fine // cfg.n_upsample_steps
            for k in range(cfg.n_upsample_steps if n_step > 0 else 0):
                w = upsample_weights(o, d, t, sdf, n, cfg.upsample_s * 2.0 ** k, field.bound)
                t_new = importance_samples(t, w, n, n_step)
                sdf_new = _sdf_along(field, o, d, t_new, n_step)

                ranks = merge_ranks(t, n, t_new, n_step)
                t, sdf = scatter_merged(*ranks, t, t_new), scatter_merged(*ranks, sdf, sdf_new)
                n += n_step
                dr.eval(t, sdf)
        return t, n
