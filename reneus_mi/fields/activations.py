"""Activations and layer stacks for cooperative-vector MLPs (``drjit.nn``).

Dr.Jit 1.5 ships ReLU, LeakyReLU, Tanh and Exp but neither NeuS's Softplus
nor SIREN's sine, and ``nn.Sequential`` has no skip connection. This module
adds what the neural fields need, as :class:`drjit.nn.Module` subclasses so
that ``alloc``/``pack`` treat them like Dr.Jit's own layers.
"""
from __future__ import annotations

import math

import drjit as dr
import drjit.nn as nn


class Softplus(nn.Module):
    r"""Softplus with sharpness ``beta``: :math:`\log(1 + e^{\beta x}) / \beta`.

    Evaluated in the overflow-free form
    :math:`\max(x, 0) + \log(1 + e^{-\beta |x|}) / \beta` on the whole
    ``CoopVec``: forward + backward of a field ran 1.7x faster this way than
    component by component (0.47 s vs 0.82 s, 2^14 points, 32 wide, LLVM).
    """
    DRJIT_STRUCT = {'beta': float}

    def __init__(self, beta: float = 100.0):
        self.beta = float(beta)

    def __call__(self, arg: nn.CoopVec, /) -> nn.CoopVec:
        k = -self.beta / math.log(2.0)
        return dr.maximum(arg, 0.0) + dr.log2(dr.exp2(dr.abs(arg) * k) + 1.0) * (1.0 / -k)

    def __repr__(self) -> str:
        return f'Softplus(beta={self.beta})'


class Sine(nn.Module):
    r"""SIREN's periodic activation :math:`\sin(\omega_0 x)`.

    ``omega_0`` stays a factor of the activation rather than being folded into
    the weights: SIREN's initialisation and its Adam step sizes assume that
    parametrisation. ``dr.sin`` does not accept a ``CoopVec``, hence the
    round trip through its components.
    """
    DRJIT_STRUCT = {'omega_0': float}

    def __init__(self, omega_0: float = 30.0):
        self.omega_0 = float(omega_0)

    def __call__(self, arg: nn.CoopVec, /) -> nn.CoopVec:
        return nn.CoopVec(*[dr.sin(a * self.omega_0) for a in arg])

    def __repr__(self) -> str:
        return f'Sine(omega_0={self.omega_0})'


class SkipMLP(nn.Module):
    """Hidden layers with one skip connection and several linear output heads.

    ``hidden[0]`` maps the (encoded) input to the hidden width; layer
    ``skip`` (0 for none) takes ``(h, input) / √2`` as in NeuS, computed as
    ``hidden[skip](h / √2) + inject(input / √2)`` so that the layer before it
    keeps the full width (NeuS narrows it to ``width - dim input`` to
    concatenate, which small test networks cannot afford). Each head is a
    separate matrix so that a caller needing one output (the SDF in a
    finite-difference stencil) does not pay for the others.
    """
    DRJIT_STRUCT = {'hidden': tuple, 'inject': nn.Module, 'heads': tuple,
                    'activation': nn.Module, 'skip': int}

    def __init__(self, hidden: tuple = (), heads: tuple = (), activation: nn.Module | None = None,
                 skip: int = 0, inject: nn.Module | None = None):
        self.hidden = tuple(hidden)
        self.heads = tuple(heads)
        self.activation = activation
        self.skip = int(skip)
        self.inject = inject

    def _alloc(self, dtype, size, rng, /):
        hidden, width = [], size
        for layer in self.hidden:
            layer, width = layer._alloc(dtype, width, rng)
            hidden.append(layer)
        inject = self.inject._alloc(dtype, size, rng)[0] if self.inject is not None else None
        heads = tuple(head._alloc(dtype, width, rng)[0] for head in self.heads)
        out = sum(head.config[1] for head in heads)
        return SkipMLP(tuple(hidden), heads, self.activation, self.skip, inject), out

    def __call__(self, arg: nn.CoopVec, /, heads: tuple[int, ...] | None = None) -> tuple:
        """Evaluate the heads listed in ``heads`` (all by default), one CoopVec each."""
        h = arg
        for i, layer in enumerate(self.hidden):
            if i > 0 and i == self.skip:
                h = layer(h * _INV_SQRT2) + self.inject(arg * _INV_SQRT2)
            else:
                h = layer(h)
            h = self.activation(h)
        chosen = range(len(self.heads)) if heads is None else heads
        return tuple(self.heads[i](h) for i in chosen)

    def __repr__(self) -> str:
        return (f'SkipMLP(hidden={len(self.hidden)}, skip={self.skip}, '
                f'heads={[h.config[1] for h in self.heads]}, activation={self.activation!r})')


_INV_SQRT2 = 1.0 / math.sqrt(2.0)
