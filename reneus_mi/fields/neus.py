"""NeuS's networks (Wang et al. 2021) as Dr.Jit cooperative-vector MLPs.

ReNeuS keeps NeuS's field unchanged inside the container: an SDF network
g(x) that also returns a feature vector, a radiance network
f(x, v, n, feature), and one learned sharpness s. Both networks are
``drjit.nn`` modules packed into one flat weight buffer each, so that a whole
evaluation (encoding, every layer, activations) fuses into the caller's
kernel and the weights are two differentiable arrays.

The building blocks (:func:`positional_encoding`, :func:`storage_types`,
:class:`~reneus_mi.fields.activations.SkipMLP`) are kept apart from
:class:`NeuSField` so that another field (e.g. a hash-grid SDF) can reuse them.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import drjit as dr
import drjit.nn as nn
import mitsuba as mi
import numpy as np

from reneus_mi.fields.activations import Sine, SkipMLP, Softplus
from reneus_mi.fields.base import Field, FieldConfig
from reneus_mi.utils import limits
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.validate import check_choice, check_numbers
from reneus_mi.utils.variant import is_cuda

# SIREN's last layer is scaled down by this factor in the SDF head only: the
# analytic sphere then dominates the initial SDF (residual ~1e-3, gradient
# perturbation a few percent) while every weight still receives a gradient.
_SIREN_SDF_GAIN = 1e-2


@dataclass
class NeuralFieldConfig(FieldConfig):
    """What every neural field shares: NeuS's radiance network and sharpness, precision, seed."""

    n_features: int = 256
    """Length of the feature vector passed from the SDF to the radiance network."""
    color_hidden: int = 256
    """Width of the radiance network."""
    color_layers: int = 4
    """Hidden (ReLU) layers of the radiance network."""
    multires_view: int = 4
    """Octaves of the positional encoding of the viewing direction."""
    init_radius: float = 0.5
    """Radius of the sphere that the untrained SDF represents."""
    init_variance: float = 0.3
    """Initial value of NeuS's ``variance``; inv_s = exp(10 * variance)."""
    dtype: str = 'auto'
    """Weight precision: 'float32', 'float16', or 'auto' (float16 on CUDA,
    where cooperative vectors pack only half precision; float32 on LLVM)."""
    seed: int = 0
    """Seed of the weight initialisation."""

    def __post_init__(self):
        check_numbers(self, positive=('n_features', 'color_hidden', 'color_layers', 'init_radius'),
                      at_least_zero=('multires_view', 'seed'), finite=('init_variance',))
        if not self.init_radius < Field.bound:
            raise ReneusError(f'{self.kind}: init_radius={self.init_radius!r}; expected a radius below '
                              f'the field bound {Field.bound}')
        check_choice(self, 'dtype', ('auto', 'float32', 'float16'))

    #: The settings that make the field large, named when it is too large.
    size_settings: ClassVar[tuple[str, ...]] = ('n_features', 'color_hidden', 'color_layers')

    def parameters(self) -> int:
        """How many numbers the field's networks and tables hold: its size before it is built."""
        n_color = 3 + 3 * (1 + 2 * self.multires_view) + 3 + self.n_features
        return mlp_size(n_color, self.color_hidden, self.color_layers, 3)


def mlp_size(n_in: int, width: int, layers: int, n_out: int) -> int:
    """Weights and biases of an MLP of ``layers`` hidden layers of ``width``."""
    return n_in * width + width * width * (layers - 1) + width * n_out + width * layers + n_out


@dataclass
class NeuSFieldConfig(NeuralFieldConfig):
    """Architecture of :class:`NeuSField`; the defaults are NeuS's (and ReNeuS's)."""

    kind: ClassVar[str] = 'neus'

    hidden: int = 256
    """Width of the SDF network."""
    layers: int = 8
    """Hidden layers of the SDF network; the encoded input is re-injected at
    layer ``layers // 2`` (NeuS: 4 of 8)."""
    multires: int = 6
    """Octaves of the positional encoding of x (frequencies 1, 2, ..., 2^(multires-1))."""
    activation: str = 'softplus'
    """'softplus' (NeuS, beta = ``beta``) or 'sine' (SIREN, as in ReNeuS's implementation)."""
    beta: float = 100.0
    """Sharpness of the Softplus activation."""
    omega_0: float = 30.0
    """Frequency factor of the sine activation, sin(omega_0 * (W h + b))."""
    fd_step: float = 1e-3
    """Step of the finite-difference SDF gradient (normals, Eikonal term)."""

    def __post_init__(self):
        super().__post_init__()
        check_numbers(self, positive=('hidden', 'layers', 'beta', 'omega_0', 'fd_step'),
                      at_least_zero=('multires',))
        check_choice(self, 'activation', ('softplus', 'sine'))

    size_settings: ClassVar[tuple[str, ...]] = ('hidden', 'layers') + NeuralFieldConfig.size_settings

    def parameters(self) -> int:
        n_pos = 3 * (1 + 2 * self.multires)
        # The encoded input is injected again halfway (the skip layer).
        return (super().parameters() + mlp_size(n_pos, self.hidden, self.layers, 1 + self.n_features)
                + n_pos * self.hidden)


def positional_encoding(values: list, octaves: int) -> list:
    """NeuS/NeRF encoding γ(p) = (p, sin(2^0 p), cos(2^0 p), ..., cos(2^(L-1) p)).

    ``values`` are the components of p (Dr.Jit arrays); the result is a list
    of ``len(values) * (1 + 2 * octaves)`` arrays, identity first.
    """
    out = list(values)
    for k in range(octaves):
        sin_cos = [dr.sincos(v * float(2 ** k)) for v in values]
        out += [s for s, _ in sin_cos] + [c for _, c in sin_cos]
    return out


def storage_types(dtype: str) -> tuple[type, type]:
    """(scalar array type, tensor type) of MLP weights for a config ``dtype``.

    Cooperative vectors on CUDA pack only half precision, so 'float32' there
    is refused here rather than deep inside ``nn.pack``.
    """
    if dtype == 'auto':
        dtype = 'float16' if is_cuda() else 'float32'
    if dtype == 'float32':
        if is_cuda():
            raise ReneusError("NeuSField: dtype='float32' is not available on CUDA "
                             "(cooperative vectors pack only half precision); use 'float16' or 'auto'")
        return mi.Float, mi.TensorXf
    half = dr.float16_array_t(mi.Float)
    return half, dr.tensor_t(half)


def _linears(mlp: SkipMLP) -> list[nn.Linear]:
    return [*mlp.hidden, *([mlp.inject] if mlp.inject is not None else []), *mlp.heads]


def _write(layer: nn.Linear, tensor_t: type, weights: np.ndarray, bias: np.ndarray | None = None) -> None:
    """Overwrite a layer's freshly allocated (Xavier) coefficients."""
    layer.weights = tensor_t(weights.astype(np.float32))
    if layer.bias is not None:
        out = layer.config[1]
        layer.bias = tensor_t(np.zeros(out, np.float32) if bias is None else bias.astype(np.float32))


def geometric_init(mlp: SkipMLP, tensor_t: type, radius: float, rng: np.random.Generator) -> None:
    """SAL's geometric initialisation (Atzmon & Lipman 2020) as done by NeuS.

    With He-normal hidden layers, ReLU-like activations preserve |h| ≈ |x|
    in expectation, and a last layer of mean √π/√width turns Σ relu(w·h)
    into |x|: g(x) ≈ |x| - radius. Only the identity part (first 3 columns)
    of the encoded input is used at the start, so the high frequencies
    enter the SDF only as training asks for them.
    """
    for i, layer in enumerate(mlp.hidden):
        fan_in, fan_out = layer.config[:2]
        w = rng.normal(0.0, math.sqrt(2.0 / fan_out), (fan_out, fan_in))
        if i == 0:
            w[:, 3:] = 0.0
        _write(layer, tensor_t, w)
    if mlp.inject is not None:
        fan_in, fan_out = mlp.inject.config[:2]
        w = rng.normal(0.0, math.sqrt(2.0 / fan_out), (fan_out, fan_in))
        w[:, 3:] = 0.0
        _write(mlp.inject, tensor_t, w)
    for head in mlp.heads:
        fan_in, fan_out = head.config[:2]
        w = rng.normal(math.sqrt(math.pi) / math.sqrt(fan_in), 1e-4, (fan_out, fan_in))
        _write(head, tensor_t, w, np.full(fan_out, -radius))


def siren_init(mlp: SkipMLP, tensor_t: type, omega_0: float, rng: np.random.Generator,
               head_gains: tuple[float, ...]) -> None:
    """SIREN's initialisation (Sitzmann et al. 2020) for sin(omega_0 (W h + b)).

    First layer U(±1/fan_in), later layers U(±√(6/fan_in)/omega_0) (the skip
    layer counts its injected inputs in fan_in), biases PyTorch's
    U(±1/√fan_in). Head ``k`` is additionally scaled by ``head_gains[k]``.
    """
    def uniform(bound, shape):
        return rng.uniform(-bound, bound, shape)

    skip_fan_in = mlp.inject.config[0] if mlp.inject is not None else 0
    for i, layer in enumerate(mlp.hidden):
        fan_out, fan_in = layer.config[1], layer.config[0]
        if i == 0:
            bound = 1.0 / fan_in
        else:
            fan_in += skip_fan_in if i == mlp.skip else 0
            bound = math.sqrt(6.0 / fan_in) / omega_0
        _write(layer, tensor_t, uniform(bound, (fan_out, layer.config[0])),
               uniform(1.0 / math.sqrt(fan_in), fan_out))
        if i > 0 and i == mlp.skip:
            _write(mlp.inject, tensor_t, uniform(bound, (fan_out, skip_fan_in)))
    for head, gain in zip(mlp.heads, head_gains):
        fan_out, fan_in = head.config[1], head.config[0]
        bound = math.sqrt(6.0 / fan_in) / omega_0
        _write(head, tensor_t, gain * uniform(bound, (fan_out, fan_in)),
               gain * uniform(1.0 / math.sqrt(fan_in), fan_out))


def fan_in_uniform_init(mlp: SkipMLP, tensor_t: type, rng: np.random.Generator) -> None:
    """PyTorch's default ``nn.Linear`` initialisation, U(±1/√fan_in) for weights
    and biases: what NeuS's radiance network starts from."""
    for layer in _linears(mlp):
        fan_in, fan_out = layer.config[:2]
        bound = 1.0 / math.sqrt(fan_in)
        _write(layer, tensor_t, rng.uniform(-bound, bound, (fan_out, fan_in)),
               rng.uniform(-bound, bound, fan_out))


def build_mlp(n_in: int, width: int, depth: int, heads: tuple[int, ...], activation: nn.Module,
              tensor_t: type, skip: int = 0) -> SkipMLP:
    """Allocate a :class:`SkipMLP` (still unpacked: initialise, then ``nn.pack``)."""
    hidden = tuple(nn.Linear(-1, width) for _ in range(depth))
    inject = nn.Linear(n_in, width, bias=False) if skip > 0 else None
    body = SkipMLP(hidden, tuple(nn.Linear(-1, n) for n in heads), activation, skip, inject)
    return body.alloc(tensor_t, n_in)


#: Bytes per parameter of a field being fitted: its value, its gradient, Adam's two moments,
#: and the packed copy the networks evaluate with and its gradient (float32 each).
BYTES_PER_PARAMETER = 24


def check_size(cfg: NeuralFieldConfig) -> None:
    """Refuse a field whose parameters exceed 32-bit indices or the machine's memory, before
    anything is allocated, naming the settings that size it."""
    n = cfg.parameters()
    settings = ', '.join(f'{name}={getattr(cfg, name)}' for name in cfg.size_settings)
    what = f'a {cfg.kind} field of {n:,} parameters ({settings}: model.field.<name>)'
    limits.check_index_range(n, what)
    limits.check_memory(n * BYTES_PER_PARAMETER, what)


class NeuralField(Field):
    """What the neural fields share: their configuration, the weights' precision, NeuS's
    radiance network f(x, v, n, feature) and the sharpness s = exp(10 variance).

    A subclass builds its SDF network after ``super().__init__`` (which draws no
    random numbers), then the radiance network with :meth:`_radiance_network`,
    and stores its own parameters in :meth:`_store`.
    """

    Config: ClassVar[type] = NeuralFieldConfig

    def __init__(self, config=None, **kwargs):
        try:
            cfg = dataclasses.replace(config or self.Config(), **kwargs)
        except TypeError:
            known = {f.name for f in dataclasses.fields(self.Config)}
            raise ReneusError(f'{type(self).__name__}: unknown option(s) {sorted(set(kwargs) - known)}; '
                              f'expected some of {sorted(known)}') from None
        self.cfg = cfg
        check_size(cfg)
        self.n_features = cfg.n_features
        self._net_t, self._tensor_t = storage_types(cfg.dtype)
        self._rng = np.random.default_rng(cfg.seed)
        # Opaque, so kernels read it from memory: a new value needs no recompilation.
        self._variance = dr.opaque(mi.Float, cfg.init_variance)

    def _radiance_network(self):
        """NeuS's radiance network, initialised as PyTorch's nn.Linear, packed."""
        cfg = self.cfg
        n_color = 3 + 3 * (1 + 2 * cfg.multires_view) + 3 + cfg.n_features
        color = build_mlp(n_color, cfg.color_hidden, cfg.color_layers, (3,), nn.ReLU(), self._tensor_t)
        fan_in_uniform_init(color, self._tensor_t, self._rng)
        return nn.pack(color, layout='training')

    def _to_net(self, values: list) -> nn.CoopVec:
        return nn.CoopVec(*[self._net_t(v) for v in values])

    def radiance(self, x: mi.Point3f, v: mi.Vector3f, n: mi.Vector3f,
                 feature: list[mi.Float]) -> mi.Color3f:
        if len(feature) != self.n_features:
            raise ReneusError(f'{type(self).__name__}.radiance: {len(feature)} feature channels, '
                              f'expected {self.n_features}')
        inputs = [x.x, x.y, x.z, *positional_encoding([v.x, v.y, v.z], self.cfg.multires_view),
                  n.x, n.y, n.z, *feature]
        (rgb,) = self.color_network(self._to_net(inputs))
        r, g, b = [mi.Float(c) for c in rgb]
        return dr.rcp(1.0 + dr.exp(-mi.Color3f(r, g, b)))

    def inv_s(self) -> mi.Float:
        return dr.exp(10.0 * self._variance)

    @staticmethod
    def variance_of(inv_s: float) -> float:
        """The value of the ``'variance'`` parameter that gives the sharpness ``inv_s``."""
        return math.log(inv_s) / 10.0

    # ---------------------------------------------------------- parameters
    def params(self) -> dict:
        return {'color.weights': self.color_network['weights'], 'variance': self._variance}

    def _assign(self, key: str, value) -> None:
        current = self.params().get(key)
        if current is None:
            super()._assign(key, value)
        if dr.width(value) != dr.width(current):
            raise ReneusError(f'{type(self).__name__}: parameter {key!r} given {dr.width(value)} values, '
                              f'expected {dr.width(current)}')
        self._store(key, value if type(value) is type(current) else type(current)(value))

    def _store(self, key: str, value) -> None:
        if key == 'variance':
            self._variance = value
        else:
            # In place: the layers' MatrixViews point into this buffer.
            self.color_network['weights'] = value

    def config(self) -> dict:
        return dataclasses.asdict(self.cfg)


class NeuSField(NeuralField):
    """NeuS's SDF, radiance and sharpness, trained inside the container.

    - SDF network: γ(x) (``multires`` octaves + identity) → ``layers`` x
      ``hidden`` with the input re-injected at ``layers // 2`` → heads
      [g(x)] and [feature(x)] (one matrix each; together NeuS's 1 + 256
      outputs). Softplus(beta=100) with SAL's geometric initialisation
      (g ≈ |x| - init_radius), or SIREN sines; SIREN has no geometric
      initialisation, so with ``activation='sine'`` the SDF is
      ``|x| - init_radius + head(x)`` with the analytic sphere added outside
      the network and the SDF head started ~100x smaller than SIREN's (the
      network learns a residual on the sphere).
    - Radiance network: (x, γ(v), n, feature) → ``color_layers`` x
      ``color_hidden`` ReLU → sigmoid RGB (linear radiance).
    - Sharpness: inv_s = exp(10 * variance), variance initialised to 0.3.

    NeuS's weight normalisation is not reproduced: packed cooperative-vector
    weights are the matrices themselves.

    Parameters (:meth:`params`) are ``'sdf.weights'`` and
    ``'color.weights'`` (packed buffers, written in place by
    :meth:`set_params` so that the layers' views stay valid) and
    ``'variance'`` (one float32).

    Precision: float32 weights on LLVM. On CUDA the weights are float16
    (``dtype='auto'``), network inputs are cast to half and outputs back to
    float32. A trainer must then keep Adam's default ``promote_fp16=True``
    (float32 moments and master copy), scale the loss with a
    ``drjit.opt.GradScaler`` built with an array scale so that its first
    back-off does not recompile::

        scaler = dr.opt.GradScaler(init_scale=mi.Float(2.0 ** 16))
        opt = mi.ad.Adam(lr=5e-4, params=field.params())
        for it in range(n):
            field.set_params(opt)
            loss = ...
            dr.backward(scaler.scale(loss))
            scaler.step(opt)   # unscales, skips the step on inf/NaN gradients

    Points are in the field's normalised frame (the object inside the unit
    sphere, ``bound`` = 1).
    """

    Config = NeuSFieldConfig

    def __init__(self, config: NeuSFieldConfig | None = None, **kwargs):
        super().__init__(config, **kwargs)
        cfg, tensor_t, rng = self.cfg, self._tensor_t, self._rng
        self.fd_step = float(cfg.fd_step)

        n_pos = 3 * (1 + 2 * cfg.multires)
        if cfg.activation == 'softplus':
            activation = Softplus(cfg.beta)
        else:
            activation = Sine(cfg.omega_0)
        sdf = build_mlp(n_pos, cfg.hidden, cfg.layers, (1, cfg.n_features), activation, tensor_t,
                        skip=cfg.layers // 2)
        if cfg.activation == 'softplus':
            geometric_init(sdf, tensor_t, cfg.init_radius, rng)
        else:
            siren_init(sdf, tensor_t, cfg.omega_0, rng, head_gains=(_SIREN_SDF_GAIN, 1.0))

        self.sdf_network = nn.pack(sdf, layout='training')
        self.color_network = self._radiance_network()

    # ------------------------------------------------------------ networks
    @staticmethod
    def _from_net(cv: nn.CoopVec) -> list:
        return [mi.Float(v) for v in cv]

    def _sdf_net(self, x: mi.Point3f, heads: tuple[int, ...]) -> list:
        enc = positional_encoding([x.x, x.y, x.z], self.cfg.multires)
        outputs = self.sdf_network(self._to_net(enc), heads=heads)
        outputs = [self._from_net(cv) for cv in outputs]
        if self.cfg.activation == 'sine':
            # SIREN has no sphere initialisation: the network is a residual on one.
            outputs[0][0] += dr.norm(x) - self.cfg.init_radius
        return outputs

    def geometry(self, x: mi.Point3f) -> tuple[mi.Float, list[mi.Float]]:
        (sdf,), feature = self._sdf_net(x, (0, 1))
        return sdf, feature

    def sdf(self, x: mi.Point3f) -> mi.Float:
        return self._sdf_net(x, (0,))[0][0]

    # ---------------------------------------------------------- parameters
    def params(self) -> dict:
        return {'sdf.weights': self.sdf_network['weights'], **super().params()}

    def _store(self, key: str, value) -> None:
        if key == 'sdf.weights':
            self.sdf_network['weights'] = value
        else:
            super()._store(key, value)
