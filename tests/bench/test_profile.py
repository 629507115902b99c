"""bench/profile.py's reading of a kernel: the FMAs and weight-gradient reductions of an MLP
of known shape, counted in the LLVM IR Dr.Jit generates for it."""
import importlib.util
import os

import drjit as dr
import mitsuba as mi
import pytest

import reneus_mi  # noqa: F401

# By its path: 'profile' is also a module of Python's own.
_spec = importlib.util.spec_from_file_location(
    'bench_profile', os.path.join(os.path.dirname(__file__), '..', '..', 'bench', 'profile.py'))
bench_profile = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_profile)

DIMS = bench_profile.MLP
WEIGHTS = sum(a * b for a, b in zip(DIMS[:-1], DIMS[1:]))


def _kernels(backward: str | None) -> list[dict]:
    net = bench_profile.mlp(DIMS)
    x = [dr.arange(mi.Float, 64) * (i + 1) for i in range(DIMS[0])]
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        dr.eval(bench_profile.mlp_output(net, x, backward))
        history = dr.kernel_history()
    return [bench_profile.ir_counts(k['ir'].getvalue()) for k in history if k['type'] == dr.KernelType.JIT]


@pytest.mark.skipif(not mi.variant().startswith('llvm'), reason="the CPU backend's IR")
def test_an_mlps_fmas_and_weight_gradients_are_counted():
    (forward,) = _kernels(backward=None)
    # Every weight once in the matrix-vector products' loops; a handful of straight-line FMAs.
    assert WEIGHTS <= forward['fma'] < WEIGHTS + 16 and forward['reductions'] == 0
    counts = _kernels(backward='weights')
    # Every weight's gradient is one reduction of a packet's lanes.
    assert sum(c['reductions'] for c in counts) == WEIGHTS
    # Backward to the inputs alone: the forward and most products again, transposed; no reductions.
    counts = _kernels(backward='inputs')
    assert sum(c['reductions'] for c in counts) == 0
    assert sum(c["fma"] for c in counts) > 1.5 * WEIGHTS
