"""How the field is fitted, as settings: the schedule, the loss's weights, what is refined.

:class:`TrainConfig` is the ``train`` half of a run's configuration (:mod:`reneus_mi.config`).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from reneus_mi.geometry.surface import POSTPROCESS_MODES
from reneus_mi.render.light import LIGHTS
from reneus_mi.train.pixel_sampler import PixelSamplerConfig
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.validate import check_choice, check_numbers

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
    """Steps before the field's first in which the absorption, the walls' thickness (where
    refined) and a block's faces' bulge (``model.render.bow``) are fitted alone, to the photographs rendered with the container empty: most of the
    container's pixels see no specimen, only the medium and the board through the glass, and
    measure them. Trained with the field from the start, a formless field takes the tint as fog
    and colour first, and fits itself to a wrong wall (a case's 3 mm glass stated 1.5: 2.16 mm
    after 10 minutes). The walls are searched for first (``wall_rays``); then the absorption's
    first half fits the pixels' median (L1), the second their mode (a robust loss whose scale
    shrinks: ``media_scale``), the specimen's pixels falling out of the fit; the field then
    refines both with the rest from ``after`` (docs/containers.md). 0: no such fit."""
    media_rays: int = 1024
    """Camera rays a step of that fit (through the centres of pixels drawn uniformly)."""
    media_learning_rate: float = 0.05
    """Peak learning rate of the absorption in that fit (per scene unit; it decays to 0 over its
    steps)."""
    wall_rays: int = 16384
    """Camera rays at which each thickness of the walls is scored before the field's first
    step (through the centres of pixels drawn uniformly; :meth:`~reneus_mi.train.trainer.Trainer.search_walls`)."""
    media_scale: tuple[float, float] = (0.1, 0.02)
    """First and last scale of the robust loss of that fit's second half
    (:func:`~reneus_mi.train.losses.welsch`, on gamma-encoded colours), shrinking geometrically:
    residuals well beyond it, the specimen's pixels, weigh nothing."""
    wall: bool = False
    """Refine the thickness of a hollow container's walls (container.wall: each inner
    interface's distance in from the one around it, a case's glass, a jar's) with the field,
    from what the scene states; the outer surface stays where the capture measured it. The
    refined container is written as container_refined.ply."""
    wall_learning_rate: float = 0.005
    """Peak learning rate of the walls' thickness, as a share of the thickest stated wall."""
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
                                      'media_rays', 'wall_rays', 'wall_learning_rate', 'pose_learning_rate', 'light_learning_rate'),
                      at_least_zero=('after', 'silhouette_weight', 'media_steps'))
        check_choice(self, 'light', ('none',) + LIGHTS[1:])
        lo, hi = self.ior_range
        if not 1.0 < lo < hi:
            raise ReneusError(f'ior_range={list(self.ior_range)}: expected 1 < low < high')

    def any(self) -> bool:
        """Whether anything besides the field is refined."""
        return (self.ior or self.inner_ior or self.absorption or self.wall or self.pose
                or self.light != 'none')

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
    sharpness_hold: float = 0.3
    """Share of the planned iterations, at their end, over which s is kept from falling below
    `sharpness_floor` times the cap."""
    sharpness_floor: float = 0.0
    """Least s over the last `sharpness_hold` of the planned iterations, as a fraction of that
    step's cap (with `sharpness_start`; 1: s held at the cap; 0: s is only capped). Why: one ray
    per pixel is fitted best by the photographs' blur, which a free s settles to: at 960 px s
    ended at 187 (0.15 mm, 0.6 of a pixel's footprint), drawing 0.2-0.4 mm legs half
    transparent, their SDF shallow and their tips short."""
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
                                     'learning_rate_alpha', 'max_minutes', 'seed', 'sharpness_start', 'sharpness_hold',
                                     'sharpness_floor'))
        check_choice(self, 'postprocess', POSTPROCESS_MODES)
        for name in ('sharpness_hold', 'sharpness_floor'):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ReneusError(f'train.{name}={getattr(self, name)}: expected a share in [0, 1]')
        if self.sharpness_floor and not self.sharpness_start:
            raise ReneusError(f'train.sharpness_floor={self.sharpness_floor}: needs train.sharpness_start '
                              '(the floor is a share of the cap)')
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

    def sharpness_min(self, it: int) -> float:
        """The least sharpness s allowed at step ``it`` (0: none)."""
        if not self.sharpness_floor or it < (1.0 - self.sharpness_hold) * self.iterations:
            return 0.0
        return self.sharpness_floor * self.sharpness_cap(it)
