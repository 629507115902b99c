"""The loss of Eq. 13 by term: L = L_color + λ1 L_trans + λ2 L_reg, over a batch of rays
(and, beyond the paper, the reach term that grows thin parts: :func:`reach`).

:func:`loss_dict` returns the paper's terms (and the container's silhouette
term while its pose is refined) by name with their weights, as nerfstudio's
``get_loss_dict``; :func:`total` is their weighted sum. The trainer's step and
a hand-written loop (``notebooks/02_reconstruction.ipynb``) use both, and the
log records each term by its name.

The batch holds only rays inside the container mask M_in (the trainer draws
them there), so the masked means of Eqs. 14-15 are plain means here.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import drjit as dr
import mitsuba as mi


class Term(NamedTuple):
    """One term of the loss: its value (a Dr.Jit scalar) and its weight."""
    value: mi.Float
    weight: float


def loss_dict(result, target: mi.Color3f, cfg, silhouette: mi.Float | None = None,
              pair: tuple[mi.Color3f, mi.Color3f] | None = None) -> dict[str, Term]:
    """The terms of a batch by name: ``color`` (Eq. 14, weight 1), ``trans`` (Eq. 15, λ1 =
    ``cfg.trans_weight``), ``eikonal`` (Eq. 16, λ2 = ``cfg.eikonal_weight``), where its weight
    is not 0 and nothing but the field is refined ``reach`` (``cfg.reach_weight``) and, given
    its value, ``silhouette`` (``cfg.refine.silhouette_weight``).

    ``result`` is :meth:`ReNeuSIntegrator.render_rays`'s, ``target`` the photographs'
    colours, ``cfg`` a :class:`~reneus_mi.train.config.TrainConfig`; ``pair``: each pixel's two
    rays' colours (``train.pixels.paired``, the share of the colour term that :func:`paired_l1`
    takes; the rest is each ray's L1).
    """
    if pair is None:
        color = color_l1(result.color, target)
    else:
        share = cfg.pixels.paired
        color = share * paired_l1(*pair, target)
        if share < 1.0:
            color += (1.0 - share) * 0.5 * (color_l1(pair[0], target) + color_l1(pair[1], target))
    terms = {'color': Term(color, 1.0),
             'trans': Term(transmittance_sparsity(result.sparsity), cfg.trans_weight),
             'eikonal': Term(eikonal(result.eikonal, result.n_samples), cfg.eikonal_weight)}
    if cfg.reach_weight and not cfg.refine.any():
        terms['reach'] = Term(reach(result, target, cfg.reach_threshold), cfg.reach_weight)
    if silhouette is not None:
        terms['silhouette'] = Term(silhouette, cfg.refine.silhouette_weight)
    return terms


def total(terms: dict[str, Term]) -> mi.Float:
    """The weighted sum of the terms, in their order."""
    loss = None
    for value, weight in terms.values():
        weighted = value if weight == 1.0 else weight * value
        loss = weighted if loss is None else loss + weighted
    return loss


def mean(x) -> mi.Float:
    """Mean over every entry of ``x``. The count reaches kernels as data: ``dr.mean`` would
    compile it in, and batches whose size changes (a sample budget) would compile anew."""
    count = dr.width(x) * (len(x) if dr.depth_v(x) > 1 else 1)
    return dr.sum(x, axis=None) / dr.opaque(mi.Float, count)


def color_l1(pred: mi.Color3f, target: mi.Color3f) -> mi.Float:
    """L_color (Eq. 14): mean L1 distance, averaged over rays and channels."""
    return mean(dr.abs(pred - target))


def paired_l1(first: mi.Color3f, second: mi.Color3f, target: mi.Color3f) -> mi.Float:
    """Beyond the paper: the colour loss of two rays through independent random points of each
    pixel, with errors a and b: mean over pixels and channels of ab / (|a| + |b|), the
    denominator held constant. Its gradient moves each ray by the other's error, which is
    independent of it: in expectation the gradient of the pixel's mean error, as the
    photograph's pixel averages what covers it. One ray against the pixel (L1 or L2 alike) is
    least for the blur of what the pixel covers: an edge drawn sharp errs on every ray, and a
    thin part is drawn half transparent. Where the two rays agree it is L1's gradient; its
    value is the L1 error of the pixels' means, as :func:`color_l1` of them."""
    a, b = first - target, second - target
    paired = mean(a * b / (dr.detach(dr.abs(a) + dr.abs(b)) + 1e-6))
    return paired + dr.detach(color_l1(0.5 * (first + second), target) - paired)


def welsch(pred: mi.Color3f, target: mi.Color3f, scale: float) -> mi.Float:
    """Welsch's robust loss of the colour differences r, mean over rays and channels of
    c² (1 - exp(-r² / 2c²)), c = ``scale``: differences well beyond c weigh nothing; fitted with
    c shrinking, the estimate goes to where most residuals are 0 (the mode), where L1 would
    settle at their median."""
    r = pred - target
    c2 = dr.opaque(mi.Float, scale * scale)
    return mean(c2 * (1.0 - dr.exp(-dr.square(r) / (2.0 * c2))))


def transmittance_sparsity(sparsity: mi.Float) -> mi.Float:
    """L_trans (Eq. 15): mean over rays of Σ_ℓ (1 - T_ℓ) over their inside segments."""
    return mean(sparsity)


def eikonal(eikonal_sum: mi.Float, n_samples: mi.Float) -> mi.Float:
    """L_reg (Eq. 16): mean of (|∇g| - 1)² over every sample of the batch."""
    return dr.sum(eikonal_sum) / dr.maximum(dr.sum(n_samples), 1.0)


def reach(result, target: mi.Color3f, threshold: float) -> mi.Float:
    """Beyond the paper: the pull that grows thin parts. A ray that misses the surface where its
    photograph shows the specimen (a leg not grown yet) passes the body at an SDF g of
    millimetres, where NeuS's density, and so the colour's gradient, is exp(-s g): nothing.
    This term is g where the ray passes nearest the surface (``result.nearest``), weighted by
    how much nearer its photograph the pixel would come were the surface there: the mean over
    channels of |pixel - photograph| where a surface of the field's colour there would move the
    pixel toward the photograph (and minus it where away), less ``threshold`` (the misfit that
    noise and the light leave everywhere), at least 0; no gradient flows through the weight.
    Its gradient lowers g there until a surface forms and the colour's gradient takes over; a
    surface grown wrongly is then undone by the colour's, as any other."""
    pixel = dr.detach(result.color)
    gain = dr.sum((pixel - target) * dr.sign(pixel - result.nearest_color), axis=0) / 3.0
    weight = dr.detach(dr.maximum(gain - threshold, 0.0))
    return mean(weight * result.nearest)


def mse(pred: mi.Color3f, target: mi.Color3f, among: mi.Bool | None = None) -> mi.Float:
    """Mean squared error of the pixel values (no gradient): what PSNR measures; ``among``: of
    those rays only (the ones drawn uniformly: rays drawn where the error is large would
    measure the worst pixels, not the photographs)."""
    error = dr.square(dr.detach(pred) - target)
    if among is None:
        return mean(error)
    kept = dr.select(among, 1.0, 0.0)
    return dr.sum(dr.sum(error, axis=0) * kept) / dr.maximum(3.0 * dr.sum(kept), 1.0)


def psnr(mse_value: float) -> float:
    """Peak signal-to-noise ratio (dB) of values in [0, 1] from their mean squared error."""
    return float('inf') if mse_value == 0 else -10.0 * math.log10(mse_value)
