"""NeuS hierarchical sampling: merge, stratified and inverse-CDF samples, weights."""
import numpy as np

import reneus_mi  # noqa: F401  (selects the variant)
import drjit as dr
import mitsuba as mi

from reneus_mi.fields import SphereField
from reneus_mi.render.ray_samplers import (SamplerConfig, composite, importance_samples, merge_ranks, merge_sorted,
                                    neus_alpha, stratified_samples)


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def test_merge_sorted_matches_numpy_sort():
    rng = np.random.default_rng(3)
    n_rays, n_a, n_b = 37, 11, 6
    # Quantised values, so that ties within and across the two lists occur.
    a = np.sort(rng.integers(0, 20, (n_rays, n_a)), axis=1).astype(np.float32)
    b = np.sort(rng.integers(0, 20, (n_rays, n_b)), axis=1).astype(np.float32)
    merged = merge_sorted(mi.Float(a.ravel()), n_a, mi.Float(b.ravel()), n_b)
    expected = np.sort(np.concatenate([a, b], axis=1), axis=1)
    np.testing.assert_array_equal(np.asarray(merged).reshape(n_rays, -1), expected)

    rank_a, rank_b = merge_ranks(mi.Float(a.ravel()), n_a, mi.Float(b.ravel()), n_b)
    ranks = np.concatenate([np.asarray(rank_a), np.asarray(rank_b)])
    np.testing.assert_array_equal(np.sort(ranks), np.arange(n_rays * (n_a + n_b)))


def test_stratified_samples():
    t_near, t_far = mi.Float(1.0, 2.0), mi.Float(3.0, 6.0)
    mid = np.asarray(stratified_samples(t_near, t_far, 4)).reshape(2, 4)
    np.testing.assert_allclose(mid, [[1.25, 1.75, 2.25, 2.75], [2.5, 3.5, 4.5, 5.5]], rtol=1e-6)
    ends = np.asarray(stratified_samples(t_near, t_far, 4, mi.Float(0.0, 0.9), include_ends=True))
    np.testing.assert_allclose(ends.reshape(2, 6), [[1, 1.0, 1.5, 2.0, 2.5, 3],
                                                    [2, 2.9, 3.9, 4.9, 5.9, 6]], rtol=1e-6)


def test_importance_samples_follow_pdf():
    n_in, n_new = 33, 2048
    t = np.stack([np.linspace(0.0, 1.0, n_in), np.linspace(2.0, 4.0, n_in) ** 1.5])
    centre = 0.5 * (t[:, :-1] + t[:, 1:])
    w = np.stack([np.exp(-((centre[0] - 0.3) / 0.05) ** 2) + 0.5 * np.exp(-((centre[0] - 0.8) / 0.1) ** 2),
                  np.where(centre[1] > 5.0, 1.0, 0.0)])
    w /= w.sum(axis=1, keepdims=True)
    w_padded = np.concatenate([w, np.full((2, 1), 123.0)], axis=1)  # last entry must be ignored
    s = importance_samples(mi.Float(t.ravel()), mi.Float(w_padded.ravel()), n_in, n_new)
    s = np.asarray(s).reshape(2, n_new)
    assert np.all(np.diff(s, axis=1) >= 0)
    for r in range(2):
        pdf = (w[r] + 1e-5) / (w[r] + 1e-5).sum()
        counts = np.histogram(s[r], bins=t[r])[0]
        # Deterministic quantiles: each section gets its expected count up to rounding.
        assert np.max(np.abs(counts - n_new * pdf)) <= 1.01
        # Within a section the samples are uniform (t linear in the CDF).
        k = np.argmax(pdf)
        inside = s[r][(s[r] >= t[r, k]) & (s[r] < t[r, k + 1])]
        expected = t[r, k] + (np.arange(len(inside)) + 0.5) / len(inside) * (t[r, k + 1] - t[r, k])
        # (up to one sample spacing: the first quantile in it need not sit half a spacing in)
        np.testing.assert_allclose(inside, expected, atol=(t[r, k + 1] - t[r, k]) / len(inside))


def test_neus_alpha_and_composite_match_numpy():
    rng = np.random.default_rng(1)
    prev, nxt = rng.normal(0, 0.1, 40), rng.normal(0, 0.1, 40)
    s = 30.0
    alpha = np.asarray(neus_alpha(mi.Float(prev), mi.Float(nxt), s))
    pc, nc = _sigmoid(s * prev), _sigmoid(s * nxt)
    expected = np.clip((pc - nc + 1e-5) / (pc + 1e-5), 0, 1)
    np.testing.assert_allclose(alpha, expected, rtol=1e-4, atol=1e-6)

    a = rng.uniform(0, 0.3, (4, 10))
    a[2, 4] = 1.0  # an opaque section: everything behind it gets weight 0
    w, trans = composite(mi.Float(a.ravel()), 10)
    t_excl = np.concatenate([np.ones((4, 1)), np.cumprod(1 - a, axis=1)[:, :-1]], axis=1)
    np.testing.assert_allclose(np.asarray(w).reshape(4, 10), a * t_excl, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(trans), np.prod(1 - a, axis=1), rtol=1e-5, atol=1e-6)


def test_upsampling_concentrates_samples_at_surface():
    field = SphereField(radius=0.5, inv_s=2000.0)
    n_rays = 8
    y = np.linspace(-0.45, 0.45, n_rays)
    o = mi.Point3f(mi.Float(np.full(n_rays, -2.0)), mi.Float(y), mi.Float(np.zeros(n_rays)))
    d = mi.Vector3f(1.0, 0.0, 0.0) + mi.Vector3f(dr.zeros(mi.Float, n_rays))
    t_near, t_far = dr.full(mi.Float, 1.0, n_rays), dr.full(mi.Float, 3.0, n_rays)
    n_coarse = 16
    t_coarse, n_c = SamplerConfig(n_coarse=n_coarse, n_fine=0).setup().sample(field, o, d, t_near, t_far)
    t, n = SamplerConfig(n_coarse=n_coarse, n_fine=32, n_upsample_steps=4).setup().sample(field, o, d, t_near, t_far)
    assert (n_c, n) == (n_coarse + 2, n_coarse + 34)
    t = np.asarray(t).reshape(n_rays, n)
    assert np.all(np.diff(t, axis=1) >= 0)
    np.testing.assert_array_equal(t[:, 0], 1.0)
    np.testing.assert_array_equal(t[:, -1], 3.0)
    hit = 2.0 - np.sqrt(0.25 - y ** 2)
    # The coarse spacing is 0.125; the fine rounds must bracket the hit far tighter.
    gap = [np.min(t[r][t[r] >= hit[r]]) - np.max(t[r][t[r] <= hit[r]]) for r in range(n_rays)]
    assert max(gap) < 0.01
    near_hit = np.abs(t[:, 1:-1] - hit[:, None]) < 0.02
    assert np.all(near_hit.sum(axis=1) >= 16)
