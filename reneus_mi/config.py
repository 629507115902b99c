"""The settings of a reconstruction, as nested dataclasses.

A :class:`ReconstructionConfig` is what a run is made of::

    ReconstructionConfig
    ├── model: ModelConfig          what is rendered (the scene's <integrator type="reneus">)
    │   ├── field: NeuSFieldConfig | HashGridFieldConfig | SphereFieldConfig | ...
    │   ├── sampler: SamplerConfig  samples per inside segment (reneus_mi.render.ray_samplers)
    │   └── render: RenderConfig    mode, D_re, terminal, gamma
    └── train: TrainConfig          how it is fitted (reneus_mi.optimize)
        └── refine: RefineConfig    beyond the paper: the container's IOR and pose, the light

Every field has its default written once, here or beside the component it
configures, and a docstring (the string literal under it) that is its
documentation and its command-line help. :mod:`reneus_mi.presets` names
complete configurations (``paper``, ``cpu``, ``demo``, ``fast``).
:func:`to_dict` and :func:`from_dict` turn a configuration into JSON and back
(a run's ``config.json``), with an error naming any unknown or mistyped key.
"""
from __future__ import annotations

import dataclasses
import math
import os
import typing
from dataclasses import dataclass

from reneus_mi.fields import FIELD_CONFIGS, FieldConfig, NeuSFieldConfig
from reneus_mi.geometry.container import CREASE_ANGLE
from reneus_mi.geometry.surface import POSTPROCESS_MODES
from reneus_mi.paper import GAMMA
from reneus_mi.render.ray_samplers import SamplerConfig
from reneus_mi.render.light import LIGHTS
from reneus_mi.train.pixel_sampler import PixelSamplerConfig
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.validate import check_choice, check_numbers

MODES = ('reneus', 'neus', 'neus_plus')
TERMINALS = ('trace', 'ambient', 'black')


@dataclass
class RenderConfig:
    """How the ray tree through the container is rendered (Sec. 3.3)."""

    mode: str = 'reneus'
    """'reneus' (the paper), 'neus' (ignores the container: plain NeuS in the field's bounding
    sphere) or 'neus_plus' (refracts once on entry, no reflection, no Fresnel weights)."""
    max_depth: int = 2
    """D_re, the number of interface events followed (the paper: 2; scenes written for a case or
    a jar get one more per inner interface, reneus_mi.data.scene_xml.hollow_depth)."""
    terminal: str = 'trace'
    """What a ray left at the depth limit sees beyond its last segment: 'trace' (the container
    without the field: its further reflections and refractions, to the backdrop or the ambient;
    the same as 'ambient' in uniform light), 'ambient' (straight on: the backdrop or C_out; wrong
    where the glass reflects totally toward a board) or 'black' (what Mitsuba's path tracer
    computes with max_depth = D_re + 1)."""
    gamma: float = GAMMA
    """Output is C^(1/gamma), the paper's camera response; 1 gives linear radiance."""
    rr_threshold: float = 0.0
    """Russian roulette on ray-tree branches whose weight β is below this: such a branch is
    followed with probability β/rr_threshold and then weighs rr_threshold, an unbiased and
    cheaper estimate of the paper's deterministic tree (0: the paper's tree, every branch)."""
    aovs: bool = False
    """Append the AOV channels mask, sparsity, nx, ny, nz to rendered images."""
    board_texels: int = 256
    """Texels along the longer side of the grid of gains fitted on the backdrop's emission
    (:class:`~reneus_mi.render.board_shading.BoardShading`: the light the container and the
    specimen let reach the printed board; 256 on a 240 mm board: about 1 mm; 0: the board
    as the scene gives it, lit evenly)."""
    crease_angle: float = CREASE_ANGLE
    """Container faces meeting at more than this angle (degrees) are not smoothed together:
    each side bends light by its own faces (a box stays a box however its file was written);
    smoother surfaces use the file's stored normals, or the mean of their faces' normals."""
    edge_margin: float = 0.0
    """Camera rays that enter or leave the container within this distance (scene units) of
    one of its crease edges are flagged, and training leaves them out of its colour loss: a
    block stated as sharp but polished round at its edges bends them otherwise than the
    model (0: every ray counts)."""

    def __post_init__(self):
        check_choice(self, 'mode', MODES)
        check_choice(self, 'terminal', TERMINALS)
        check_numbers(self, at_least_zero=('max_depth', 'rr_threshold', 'board_texels', 'edge_margin'),
                      positive=('gamma',))
        if not 0.0 <= self.crease_angle <= 180.0:
            raise ReneusError(f'crease_angle={self.crease_angle}: expected degrees in [0, 180]')


@dataclass
class ModelConfig:
    """What the ``reneus`` integrator renders: the field, its sampling and the ray tree."""

    field: FieldConfig = dataclasses.field(default_factory=NeuSFieldConfig)
    """The field inside the container (its kind and architecture)."""
    sampler: SamplerConfig = dataclasses.field(default_factory=SamplerConfig)
    """Samples per inside segment."""
    render: RenderConfig = dataclasses.field(default_factory=RenderConfig)
    """The ray tree through the container."""


@dataclass
class RefineConfig:
    """Beyond the paper, which takes the container and the light as known: what is refined with
    the field. Each quantity is a parameter group of its own (its learning rate follows the
    field's schedule) that starts moving after ``after`` steps. The integrator is told what is
    refined (``configure(refine=...)``): the pose and the light are then its parameters, starting
    where the scene puts the container and from the scene's emitter."""

    ior: bool = False
    """Refine the container's IOR with the field."""
    ior_learning_rate: float = 2e-3
    """Peak learning rate of the IOR."""
    ior_range: tuple[float, float] = (1.05, 2.5)
    """Bounds of the refined IOR."""
    inner_ior: bool = False
    """Refine the IORs inside the container's inner interfaces (a jar's liquid:
    container.inner_ior) with the field, at the IOR's rate, within 1 and the IOR's upper bound."""
    absorption: bool = False
    """Refine the absorption coefficient of the container's medium (RGB, per scene unit:
    container.sigma_a) with the field, from the scene's medium (0 where it has none): amber,
    tinted resin."""
    absorption_learning_rate: float = 5e-3
    """Peak learning rate of the absorption coefficient (per scene unit)."""
    media_steps: int = 150
    """Steps before the field's first in which the absorption (where refined) is fitted alone,
    to the photographs rendered with the container empty: most of the container's pixels see
    no specimen, only the medium, and measure it. Trained with the field from the start, a
    formless field takes the tint as fog and colour first. The first half fits the pixels'
    median (L1), the second their mode (a robust loss whose scale shrinks: ``media_scale``),
    the specimen's pixels falling out of the fit; the field then refines it with the rest from
    ``after`` (docs/containers.md). 0: no such fit."""
    media_rays: int = 1024
    """Camera rays a step of that fit (through the centres of pixels drawn uniformly)."""
    media_learning_rate: float = 0.05
    """Peak learning rate of that fit (per scene unit; it decays to 0 over its steps)."""
    media_scale: tuple[float, float] = (0.1, 0.02)
    """First and last scale of the robust loss of that fit's second half
    (:func:`~reneus_mi.train.losses.welsch`, on gamma-encoded colours), shrinking geometrically:
    residuals well beyond it, the specimen's pixels, weigh nothing."""
    pose: bool = False
    """Refine the container's position, rotation and per-axis scale with the field
    (container.translation, .rotation, .log_scale); the refined container is written as
    container_refined.ply."""
    pose_learning_rate: float = 1e-3
    """Peak learning rate of the pose (world units, radians, log-scale)."""
    silhouette_weight: float = 0.01
    """Weight of the container's silhouette against masks segmented from the photographs, per
    pixel of distance, while the pose is refined (0: refraction alone moves it)."""
    light: str = 'none'
    """Refine the light outside the container: 'none' (the scene's emitter as given), 'ambient'
    (one RGB radiance: light.radiance) or 'sh' (spherical harmonics up to order 2, for rooms
    that are not uniform: light.sh)."""
    light_learning_rate: float = 5e-3
    """Peak learning rate of the light."""
    after: int = 100
    """Steps of field-only training before the IOR, pose and light start to move (a formless
    field gives them no signal to follow)."""

    def __post_init__(self):
        check_numbers(self, positive=('ior_learning_rate', 'absorption_learning_rate', 'media_learning_rate',
                                      'media_rays', 'pose_learning_rate', 'light_learning_rate'),
                      at_least_zero=('after', 'silhouette_weight', 'media_steps'))
        check_choice(self, 'light', ('none',) + LIGHTS[1:])
        lo, hi = self.ior_range
        if not 1.0 < lo < hi:
            raise ReneusError(f'ior_range={list(self.ior_range)}: expected 1 < low < high')

    def any(self) -> bool:
        """Whether anything besides the field is refined."""
        return self.ior or self.inner_ior or self.absorption or self.pose or self.light != 'none'

    def light_model(self) -> str:
        """The light as the integrator models it (one of :data:`~reneus_mi.render.light.LIGHTS`)."""
        return 'emitter' if self.light == 'none' else self.light


@dataclass
class TrainConfig:
    """How the field is fitted to the photographs (Sec. 3.4)."""

    iterations: int = 3000
    """Optimisation steps (the paper: 200k on a GPU)."""
    max_minutes: float = 0.0
    """Wall-clock budget of the training in minutes: the run trains until it is spent, then
    writes its mesh, and the schedules (learning-rate decay, annealing, the field's
    coarse-to-fine levels, when refinement starts) follow the share of the budget spent,
    laid over `iterations` steps, so the run ends sharp whatever the machine's speed
    (0: no budget, train for `iterations` steps)."""
    batch_rays: int = 1024
    """Camera rays per step, drawn at random from the container masks of all views (with a
    sample budget: the first step's)."""
    pixels: PixelSamplerConfig = dataclasses.field(default_factory=PixelSamplerConfig)
    """Which pixels a batch draws and where in each its ray goes (thin parts)."""
    sample_budget: int = 0
    """Field samples per step: the batch then grows or shrinks each step (by 256 rays, up to 8x
    either way) to render about this many, so that rays the occupancy grid makes cheap fill the
    device; each batch size compiles its kernels once (0: a fixed batch)."""
    learning_rate: float = 5e-4
    """Peak learning rate of Adam (NeuS); the field scales it per parameter group."""
    learning_rate_alpha: float = 0.05
    """Final learning rate as a fraction of the peak, reached by cosine decay (NeuS)."""
    warm_up: int = 100
    """Steps of linear learning-rate warm-up (NeuS: 5000 of 300k)."""
    anneal_end: int = 0
    """Steps over which NeuS's cosine annealing ratio goes from 0 to 1 (0: no annealing)."""
    sharpness_start: float = 0.0
    """Cap on NeuS's sharpness s at the first step (0: no cap, s is learned freely as in NeuS).
    The cap rises geometrically to `sharpness_end` over the planned `iterations` (under a time
    budget, its share, as the other schedules). Why: a missing leg's rays pass the body at an
    SDF of millimetres, where NeuS's density is exp(-s g); a field that sharpens before its thin
    parts have grown out leaves them as stumps (sharp photographs make s race: 393 by a sixth
    of a 12 MP run)."""
    sharpness_end: float = 512.0
    """Cap on the sharpness s at the end of the planned iterations, and after (with
    `sharpness_start`)."""
    trans_weight: float = 0.1
    """λ1, weight of the transmittance sparsity prior L_trans (0 disables it)."""
    eikonal_weight: float = 0.1
    """λ2, weight of the Eikonal regulariser L_reg."""
    reach_weight: float = 0.0
    """Weight of the `reach` term (beyond the paper; 0 disables it): rays whose pixel the
    field misses lower the SDF where they pass nearest the surface, so that legs and antennae
    grow out where NeuS's density gives them no gradient (`reneus_mi.train.losses.reach`).
    Not while the glass or the light is refined (`refine`): the field then grows what the
    glass's error leaves in the pixels, and takes part of it (a refined IOR came out 1.465 for
    1.45 with it)."""
    reach_threshold: float = 0.05
    """Pixel misfit (mean over channels, pixel values in [0, 1]) below which a ray does not
    pull with `reach`: what noise and the light leave everywhere."""
    seed: int = 0
    """Seed of the ray batches and the stratified jitter: a fixed seed gives the same run."""
    log_every: int = 1
    """Steps between lines of log.jsonl."""
    validate_every: int = 500
    """Steps between validation renders (image + normal map, PNG) and mesh snapshots (0: never)."""
    validation_view: int = 0
    """Index of the view rendered for validation."""
    checkpoint_every: int = 100
    """Steps between checkpoints (written atomically; --resume continues from the last)."""
    mesh_resolution: int = 256
    """Marching-cubes grid points per axis of the container's box for the final mesh, laid over
    the part that holds the surface only (at least: a field whose finest level is finer is
    meshed at that, up to 512^3 points over that part)."""
    max_image_size: int = 0
    """Longest side, in pixels, of the photographs as the run fits them: larger ones are
    reduced as they load (area averaging; cameras and masks follow), which lowers the memory
    they take (0: as they are)."""
    postprocess: str = 'clean'
    """Mesh post-processing: 'clean' (join the pieces the field joins within its blur 1/s, drop
    floating fragments, keep parts that noise cut off next to the body), 'largest' (keep the
    largest connected component: the paper), 'crop' (drop what lies outside the container) or
    'none'."""
    divergence_factor: float = 50.0
    """Stop when the loss exceeds this multiple of its lowest value so far (after warm-up)."""
    refine: RefineConfig = dataclasses.field(default_factory=RefineConfig)
    """What is refined with the field beyond the paper: the container's IOR and pose, the light."""

    def __post_init__(self):
        check_numbers(self, positive=('iterations', 'batch_rays', 'mesh_resolution', 'log_every',
                                      'learning_rate', 'divergence_factor'),
                      at_least_zero=('sample_budget', 'warm_up', 'anneal_end', 'validate_every', 'checkpoint_every',
                                     'max_image_size',
                                     'validation_view', 'trans_weight', 'eikonal_weight', 'reach_weight',
                                     'reach_threshold',
                                     'learning_rate_alpha', 'max_minutes', 'seed', 'sharpness_start'))
        check_choice(self, 'postprocess', POSTPROCESS_MODES)
        if self.sharpness_start and not self.sharpness_end >= self.sharpness_start:
            raise ReneusError(f'train.sharpness_end={self.sharpness_end}: expected at least '
                              f'train.sharpness_start={self.sharpness_start}')

    def learning_rate_at(self, it: int) -> float:
        """NeuS's schedule: linear warm-up, then cosine decay to ``learning_rate_alpha``."""
        if it < self.warm_up:
            return self.learning_rate * (it + 1) / self.warm_up
        progress = min((it - self.warm_up) / max(self.iterations - self.warm_up, 1), 1.0)
        a = self.learning_rate_alpha
        return self.learning_rate * ((math.cos(math.pi * progress) + 1.0) * 0.5 * (1 - a) + a)

    def cos_anneal_ratio(self, it: int) -> float:
        return 1.0 if self.anneal_end == 0 else min(1.0, it / self.anneal_end)

    def sharpness_cap(self, it: int) -> float:
        """The largest sharpness s allowed at step ``it`` (inf: no cap)."""
        if not self.sharpness_start:
            return math.inf
        progress = min(it / self.iterations, 1.0)
        return self.sharpness_start * (self.sharpness_end / self.sharpness_start) ** progress


@dataclass
class ReconstructionConfig:
    """A whole reconstruction: the model that is rendered and how it is trained."""

    model: ModelConfig = dataclasses.field(default_factory=ModelConfig)
    """What is rendered."""
    train: TrainConfig = dataclasses.field(default_factory=TrainConfig)
    """How it is fitted."""

    def __post_init__(self):
        if self.train.refine.any() and self.model.render.mode == 'neus':
            raise ReneusError('train.refine (ior, absorption, pose, light) needs a container: mode is neus')


# --------------------------------------------------------- dicts and JSON
def to_dict(cfg) -> dict:
    """Nested plain dict of a config (a field config records its ``kind``)."""
    out = {}
    if getattr(cfg, 'kind', None):
        out['kind'] = cfg.kind
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        out[f.name] = to_dict(value) if dataclasses.is_dataclass(value) else \
            (list(value) if isinstance(value, tuple) else value)
    return out


def from_dict(cls, values: dict, where: str = ''):
    """Rebuild ``cls`` from :func:`to_dict`'s output; unknown keys are errors naming their path.

    A key left out keeps its default, so old files stay readable when a setting is added.
    """
    if not isinstance(values, dict):
        raise ReneusError(f'{where or cls.__name__}: expected a mapping of settings, got {values!r}')
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in values.items():
        path = f'{where}.{key}' if where else key
        if key == 'kind' and getattr(cls, 'kind', None):
            continue
        if key not in known:
            raise ReneusError(f"{path}: unknown setting; expected one of {', '.join(known)}")
        kind = hints[key]
        if kind is FieldConfig or (isinstance(kind, type) and dataclasses.is_dataclass(kind)):
            if kind is FieldConfig:
                kind = field_config_class(value.get('kind') if isinstance(value, dict) else None, path)
            kwargs[key] = from_dict(kind, value, path)
        else:
            kwargs[key] = typed_value(value, kind, path)
    try:
        return cls(**kwargs)
    except ReneusError as e:
        raise ReneusError(f'{where}: {e}' if where else str(e)) from None


def field_config_class(kind: str | None, where: str) -> type:
    if kind not in FIELD_CONFIGS:
        raise ReneusError(f"{where}.kind={kind!r}: unknown field kind; expected one of "
                          f"{', '.join(FIELD_CONFIGS)}")
    return FIELD_CONFIGS[kind]


def typed_value(value, kind, path: str):
    """``value`` checked against a field's type (int, float, str, bool, tuple of floats)."""
    origin = typing.get_origin(kind)
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif kind is str:
        ok = isinstance(value, str)
    elif origin is tuple or kind is tuple:
        ok = isinstance(value, (list, tuple)) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        value = tuple(float(v) for v in value) if ok else value
    else:
        ok = True
    if not ok:
        name = {bool: 'true or false', int: 'an integer', float: 'a number', str: 'a string'}.get(
            kind, 'a list of numbers')
        raise ReneusError(f'{path}={value!r}: expected {name}')
    return value


def text_value(text: str, kind, path: str):
    """A setting given as text (a command line) as a value of ``kind``: an int, float, str,
    ``true``/``false``, numbers separated by commas for a tuple, a field kind's name for the
    field (its defaults); checked by :func:`typed_value`."""
    if kind is FieldConfig:
        if text not in FIELD_CONFIGS and (text.endswith('.npz') or os.sep in text or os.path.exists(text)):
            kinds = ', '.join(FIELD_CONFIGS)
            if not os.path.isfile(text):
                raise ReneusError(f'{path}={text!r}: no such file; expected a field kind ({kinds})')
            raise ReneusError(f'{path}={text!r} is a saved field, and a setting takes a field kind ({kinds}); '
                              f'render a saved field with python -m reneus_mi.render SCENE --field {text}, or '
                              f'name it in a scene: <string name="field" value="{text}"/>')
        return field_config_class(text, path)()
    value = text
    try:
        if kind is bool:
            value = {'true': True, 'false': False}.get(text.lower(), text)
        elif kind in (int, float):
            value = kind(text)
        elif typing.get_origin(kind) is tuple or kind is tuple:
            value = [float(v) for v in text.split(',')]
    except ValueError:
        pass  # typed_value names what was expected
    return typed_value(value, kind, path)


def setting_type(cfg, path: str):
    """The type that ``cfg`` declares for the dotted ``path`` (``model.sampler.n_coarse``: int;
    under ``model.field`` the fields of the configuration's own field kind)."""
    node, kind, done = cfg, None, []
    for name in path.split('.'):
        if not dataclasses.is_dataclass(node):
            raise ReneusError(f"{path}: {'.'.join(done)} is a value, not a group of settings")
        known = [f.name for f in dataclasses.fields(node)]
        if name not in known:
            where = '.'.join(done) or 'the configuration'
            raise ReneusError(f"{path}: not a setting; {where} has {', '.join(known)}")
        kind, node = typing.get_type_hints(type(node))[name], getattr(node, name)
        done.append(name)
    return kind


def parse_setting(cfg, text: str) -> tuple[str, object]:
    """``'model.sampler.n_coarse=32'`` as ``('model.sampler.n_coarse', 32)``, typed as ``cfg``
    declares it: the one reader of settings given as text (``--set`` of scene, optimize and
    the benchmarks)."""
    path, sep, value = text.partition('=')
    if not sep or not path:
        raise ReneusError(f'{text!r}: expected PATH=VALUE (e.g. model.sampler.n_coarse=32)')
    return path, text_value(value, setting_type(cfg, path), path)


def with_settings(cfg, texts) -> tuple[object, dict]:
    """``cfg`` with the settings ``texts`` (``PATH=VALUE`` each, in order: ``model.field=hashgrid``
    before the new field's own settings), each checked; and the changes by path."""
    changes = {}
    for text in texts:
        path, value = parse_setting(cfg, text)
        cfg = replace(cfg, **{path: value})
        changes[path] = value
    return cfg, changes


def replace(cfg, **changes):
    """``dataclasses.replace`` for nested configs: keys may be dotted paths (``train.iterations``)."""
    nested: dict[str, dict] = {}
    flat = {}
    for key, value in changes.items():
        head, _, rest = key.partition('.')
        if rest:
            nested.setdefault(head, {})[rest] = value
        else:
            flat[key] = value
    for head, sub in nested.items():
        flat[head] = replace(getattr(cfg, head), **sub)
    return dataclasses.replace(cfg, **flat)
