"""The steps' random numbers: each step's batch is a fresh draw, not a lane-shifted copy of
another step's (PCG32 seeded with unmixed step numbers drew the same pixels every third step)."""
import mitsuba as mi
import numpy as np

from reneus_mi.render.seeds import PIXELS, opaque_seed, step_seed

#: Pixels to draw from (a 960x640 capture's masks hold about this many) and the batch.
POPULATION, BATCH = 10_000_000, 1024


def _batch(step: int) -> np.ndarray:
    rng = mi.PCG32(BATCH, initstate=opaque_seed(step_seed(0, step, PIXELS)))
    return np.array(rng.next_uint32_bounded(POPULATION))


def test_steps_draw_independent_batches():
    # Unmixed seeds: step 3 shared 1007 of step 0's 1024 pixels (this test fails on it), and
    # 100 steps met 4,648 distinct pixels where uniform draws meet 101,877. Uniform draws
    # share ~0.1 pixels per pair of steps.
    batches = [_batch(step) for step in range(200)]
    shared = max(len(np.intersect1d(batches[0], b)) for b in batches[1:16])
    assert shared <= 3, shared
    expected = POPULATION * (1.0 - np.exp(-len(batches) * BATCH / POPULATION))
    assert len(np.unique(np.concatenate(batches))) > 0.99 * expected


def test_seeds_depend_on_seed_step_and_stream_only():
    assert step_seed(0, 5, PIXELS) == step_seed(0, 5, PIXELS)
    seeds = {step_seed(s, t, k) for s in range(3) for t in range(100) for k in range(2)}
    assert len(seeds) == 600 and all(0 <= x < 2 ** 64 for x in seeds)
