"""An occupancy grid of the field: where the surface can be, for empty-space skipping.

The grid covers the field's cube [-bound, bound]^3 with ``resolution``^3 cells.
A cell is *occupied* when its centre's SDF satisfies

    g(c) <= L r + m + ln(1/τ) / s,

r the half diagonal of a cell, L a safety factor on the SDF's Lipschitz
constant, m a margin and s NeuS's sharpness. The argument: if |∇g| <= L, every
point x of the cell has g(x) >= g(c) - L r, so a cell that fails the test has
g > m + ln(1/τ)/s everywhere in it. There NeuS's density is negligible: a
stretch along which g stays above δ > 0 has opacity at most
1 - Φ_s(δ) <= exp(-s δ), below τ = 1e-4 for δ = ln(1/τ)/s; the margin m covers
what the bound leaves out (NeuS extrapolates a section's end values linearly,
so they undershoot g by up to L times half the section; a grid refreshed only
every few steps lags the trained SDF). A true distance has L = 1; a field in
training is only near one (the Eikonal term is a penalty), hence L > 1.

Cells inside the solid (g < 0) count as occupied as well: NeuS renders a ray
that goes deeper into the solid as opaque, so a segment that starts there
must be sampled.

:meth:`OccupancyGrid.span` marches a batch of segments through the grid (a
3D-DDA in one symbolic loop, every cell a segment crosses is visited) and
returns, per segment, the span from its first to its last occupied cell.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from reneus_mi.utils import limits

#: Opacity left to the parts of a segment that the grid removes (τ above).
OPACITY_CUTOFF = 1e-4
#: Bytes per cell of the grid (its flag) and of its update, which evaluates the SDF at every cell
#: centre in one fused launch: an upper estimate (peak RSS grew by well under 1 byte per cell
#: from 128^3 to 320^3) that only has to tell a grid that fits from one that cannot.
BYTES_PER_CELL = 8


class OccupancyGrid:
    """``resolution``^3 cells over [-bound, bound]^3; :meth:`update` fills them from a field's SDF."""

    def __init__(self, resolution: int, bound: float, *, lipschitz: float, margin: float):
        self.resolution = int(resolution)
        self.bound = float(bound)
        self.lipschitz = float(lipschitz)
        self.margin = float(margin)
        self.cell = 2.0 * self.bound / self.resolution
        #: Occupancy per cell, flat index (k * res + j) * res + i for the cell (i, j, k) along (x, y, z).
        self.occupied = dr.zeros(mi.Bool, self.resolution ** 3)

    @staticmethod
    def check_size(resolution: int) -> None:
        """Refuse a grid past 32-bit indices or the machine's memory before any is built."""
        what = f'model.sampler.occupancy_resolution={resolution} ({resolution ** 3:,} cells)'
        limits.check_index_range(resolution ** 3, what)
        limits.check_memory(resolution ** 3 * BYTES_PER_CELL, what)

    def threshold(self, inv_s: float) -> float:
        """The largest centre SDF value of an occupied cell (see the module docstring)."""
        half_diagonal = 0.5 * math.sqrt(3.0) * self.cell
        return self.lipschitz * half_diagonal + self.margin + math.log(1.0 / OPACITY_CUTOFF) / inv_s

    def centres(self) -> mi.Point3f:
        """Cell centres, in the grid's flat order."""
        res = self.resolution
        idx = dr.arange(mi.UInt32, res ** 3)
        i, j, k = idx % res, (idx // res) % res, idx // (res * res)
        return mi.Point3f(mi.Float(i), mi.Float(j), mi.Float(k)) * self.cell + (0.5 * self.cell - self.bound)

    def update(self, field) -> None:
        """Re-evaluate the field's SDF at every cell centre (one kernel, no gradient)."""
        with dr.suspend_grad():
            inv_s = float(dr.detach(field.inv_s())[0])
            # Opaque: the threshold follows the sharpness s, and a literal would compile the
            # update anew every time.
            self.occupied = field.sdf(self.centres()) <= dr.opaque(mi.Float, self.threshold(inv_s))
            dr.eval(self.occupied)

    def fraction(self) -> float:
        """Share of the cells that are occupied."""
        return dr.count(self.occupied)[0] / self.resolution ** 3

    def span(self, o: mi.Point3f, d: mi.Vector3f, t_near: mi.Float,
             t_far: mi.Float) -> tuple[mi.Float, mi.Float]:
        """Per segment ``o + t d``, t in [t_near, t_far]: the span [first, last] of its occupied cells.

        ``first`` is where the segment enters its first occupied cell, ``last``
        where it leaves its last one (both clamped to the segment); a segment
        that crosses none gets ``first = +inf > last``. Parts of a segment outside
        the cube count as occupied (the grid knows nothing there).
        """
        res = self.resolution
        inf = mi.Float(math.inf)
        q0 = (o + self.bound) * (1.0 / self.cell)  # grid coordinates: cell (i, j, k) is [i, i+1) x ...
        dq = d * (1.0 / self.cell)
        # Entry and exit of the cube [0, res]^3, axis by axis (a slab test).
        t_in, t_out = mi.Float(t_near), mi.Float(t_far)
        for a in range(3):
            q, v = q0[a], dq[a]
            flat = v == 0.0
            inv = dr.rcp(dr.select(flat, 1.0, v))
            t0, t1 = -q * inv, (res - q) * inv
            inside_slab = (q >= 0.0) & (q <= res)
            t_in = dr.maximum(t_in, dr.select(flat, dr.select(inside_slab, -inf, inf), dr.minimum(t0, t1)))
            t_out = dr.minimum(t_out, dr.select(flat, dr.select(inside_slab, inf, -inf), dr.maximum(t0, t1)))
        crosses = t_in < t_out
        # Conservative outside the cube: a segment keeps the parts before it enters
        # and after it leaves, and all of itself if it misses the cube.
        starts_out = crosses & (t_in > t_near)
        ends_out = crosses & (t_out < t_far)
        misses = (t_in >= t_out) & (t_near < t_far)
        first = dr.select(starts_out | misses, t_near, inf)
        last = dr.select(misses, t_far, dr.select(starts_out, t_in, -inf))

        # 3D-DDA (Amanatides & Woo) from the entry cell to the exit.
        start = q0 + dq * t_in
        idx, step, t_next, t_delta = [], [], [], []
        for a in range(3):
            v = dq[a]
            i = dr.clip(mi.Int32(dr.floor(start[a])), 0, res - 1)
            s = dr.select(v > 0.0, mi.Int32(1), mi.Int32(-1))
            boundary = mi.Float(i) + dr.select(v > 0.0, 1.0, 0.0)
            flat = v == 0.0
            inv = dr.rcp(dr.select(flat, 1.0, v))
            idx.append(i)
            step.append(s)
            t_next.append(dr.select(flat, inf, (boundary - q0[a]) * inv))
            t_delta.append(dr.select(flat, inf, dr.abs(inv)))
        occupied = self.occupied

        def cond(active, ix, iy, iz, nx, ny, nz, t, first, last):
            return active

        def body(active, ix, iy, iz, nx, ny, nz, t, first, last):
            exit_ = dr.minimum(dr.minimum(dr.minimum(nx, ny), nz), t_out)
            occ = dr.gather(mi.Bool, occupied, mi.UInt32((iz * res + iy) * res + ix), active)
            first = dr.select(active & occ, dr.minimum(first, t), first)
            last = dr.select(active & occ, dr.maximum(last, exit_), last)
            go_x = (nx <= ny) & (nx <= nz)
            go_y = ~go_x & (ny <= nz)
            go_z = ~go_x & ~go_y
            ix = dr.select(go_x, ix + step[0], ix)
            iy = dr.select(go_y, iy + step[1], iy)
            iz = dr.select(go_z, iz + step[2], iz)
            nx = dr.select(go_x, nx + t_delta[0], nx)
            ny = dr.select(go_y, ny + t_delta[1], ny)
            nz = dr.select(go_z, nz + t_delta[2], nz)
            in_grid = (ix >= 0) & (ix < res) & (iy >= 0) & (iy < res) & (iz >= 0) & (iz < res)
            active = active & (exit_ < t_out) & in_grid
            return active, ix, iy, iz, nx, ny, nz, exit_, first, last

        state = dr.while_loop((mi.Bool(crosses), *idx, *t_next, mi.Float(t_in), first, last), cond, body,
                              labels=('active', 'ix', 'iy', 'iz', 'nx', 'ny', 'nz', 't', 'first', 'last'))
        first, last = state[-2], state[-1]
        return dr.select(ends_out, dr.minimum(first, t_out), first), dr.select(ends_out, t_far, last)
