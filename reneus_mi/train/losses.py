"""The loss of Eq. 13: L = L_color + λ1 L_trans + λ2 L_reg, over a batch of rays.

The batch holds only rays inside the container mask M_in (the trainer draws
them there), so the masked means of Eqs. 14-15 are plain means here.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi


def mean(x) -> mi.Float:
    """Mean over every entry of ``x``. The count reaches kernels as data: ``dr.mean`` would
    compile it in, and batches whose size changes (a sample budget) would compile anew."""
    count = dr.width(x) * (len(x) if dr.depth_v(x) > 1 else 1)
    return dr.sum(x, axis=None) / dr.opaque(mi.Float, count)


def color_l1(pred: mi.Color3f, target: mi.Color3f) -> mi.Float:
    """L_color (Eq. 14): mean L1 distance, averaged over rays and channels."""
    return mean(dr.abs(pred - target))


def transmittance_sparsity(sparsity: mi.Float) -> mi.Float:
    """L_trans (Eq. 15): mean over rays of Σ_ℓ (1 - T_ℓ) over their inside segments."""
    return mean(sparsity)


def eikonal(eikonal_sum: mi.Float, n_samples: mi.Float) -> mi.Float:
    """L_reg (Eq. 16): mean of (|∇g| - 1)² over every sample of the batch."""
    return dr.sum(eikonal_sum) / dr.maximum(dr.sum(n_samples), 1.0)


def psnr(pred: mi.Color3f, target: mi.Color3f) -> float:
    mse = float(mean(dr.square(dr.detach(pred) - target))[0])
    return float('inf') if mse == 0 else -10.0 * dr.log(mse) / dr.log(10.0)
