"""Fitting the ``reneus`` integrator's field to posed photographs (Sec. 3.4).

Each step draws ``batch_rays`` pixels at random among the container-mask
pixels of all views (:class:`~reneus_mi.train.pixel_sampler.PixelSampler`; under a
``sample_budget`` the batch follows the samples per ray), renders them with
:meth:`ReNeuSIntegrator.render_rays` (what ``mi.render`` runs too), and takes
one ``mi.ad.Adam`` step on L = L_color + λ1 L_trans + λ2 L_reg (+ the
container's silhouette term while its pose is refined). The parameters are
``mi.traverse(scene)``'s view of the field's own arrays, and of the IOR, pose
and light a run refines (:mod:`reneus_mi.render.surroundings`), updated with
``params.update(opt)``, as in a hand-written Mitsuba optimisation loop.
The run lives in one output folder (:class:`~reneus_mi.train.run_folder.RunFolder`:
its files, its log, its lock and its state).
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import time
import warnings
from dataclasses import asdict, dataclass, replace

import drjit as dr
from drjit.opt import GradScaler
import mitsuba as mi
import numpy as np
from tqdm import tqdm
import trimesh

from reneus_mi.train.config import TrainConfig
from reneus_mi.data import Dataset
from reneus_mi.data.images import write_image
from reneus_mi.fields import load_field
from reneus_mi.geometry.mesh import gltf_from_world, write_glb, write_mesh
from reneus_mi.geometry.surface import components, field_colors, field_mesh, surface_box
from reneus_mi.geometry.frame import FieldFrame
from reneus_mi.render.loading import reneus_integrator
from reneus_mi.render.seeds import JITTER, MEDIA, step_seed
from reneus_mi.render.step_state import StepState
from reneus_mi.render.bow import ContainerBow
from reneus_mi.render.walls import ContainerWalls
from reneus_mi.train import checkpoint, losses
from reneus_mi.train.pixel_sampler import PixelSampler
from reneus_mi.train.run_folder import RunFolder
from reneus_mi.train.silhouette import SilhouetteLoss
from reneus_mi.utils import interrupt, limits
from reneus_mi.utils.errors import NoSurfaceError, ReneusError
from reneus_mi.utils.variant import is_cuda

#: Most grid points of the final mesh's grid, over the part of the container that holds the
#: surface, that following the field's detail chooses (512^3 and its clean-up peak at about
#: 3 GB).
MAX_AUTO_MESH_POINTS = 512 ** 3
#: The walls' thicknesses first scored, times the stated one (a guess 2.5x off either way
#: still bracketed: about 17 % apart).
WALL_SEARCH = tuple(np.geomspace(0.4, 2.5, 13))
#: Golden sections about the best of them (each shrinks the bracket by GOLDEN: 8 take its
#: 34 % to 0.4 % of the stated thickness).
WALL_GOLDEN = 8
GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)
#: A face's bulges first scored, times its smaller half-side: from 4 % in (concave) to 4 % out,
#: BOW_STEP apart (Blender's block bowed 0.3 mm: 2.7 % of its sides' 11 mm, 2 % of its top's 15).
BOW_STEP = 0.01
BOW_SEARCH = tuple(np.arange(-4, 5) * BOW_STEP)
#: Rounds over the six faces (one face's bulge moves what another's rays see: Blender's block's
#: bottom came out 0.08 mm after one, 0.02 after two; its truth 0).
BOW_PASSES = 2
#: Rays per kernel launch when rendering a whole view.
RENDER_CHUNK = 1 << 14
#: Mask margin while the container's pose is refined, as a fraction of the container's size in
#: the image: covers the 2-5 % pose errors a calibration leaves.
POSE_MARGIN = 0.1


def golden_search(loss, grid: np.ndarray) -> float:
    """Where ``loss`` is least: the best of ``grid`` (ascending), then :data:`WALL_GOLDEN`
    golden sections of the bracket of its neighbours (one new score each)."""
    best = int(np.argmin([loss(x) for x in grid]))
    a, b = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    c, d = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
    fc, fd = loss(c), loss(d)
    for k in range(WALL_GOLDEN):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - GOLDEN * (b - a)
            if k + 1 < WALL_GOLDEN:
                fc = loss(c)
        else:
            a, c, fc = c, d, fd
            d = a + GOLDEN * (b - a)
            if k + 1 < WALL_GOLDEN:
                fd = loss(d)
    return float(0.5 * (a + b))


#: Batches under a sample budget are multiples of this many rays, between the configured
#: batch / BUDGET_RANGE and batch x BUDGET_RANGE.
BATCH_QUANTUM, BUDGET_RANGE = 256, 8


def next_batch(cfg: TrainConfig, samples_per_ray: float) -> int:
    """The batch that renders about ``cfg.sample_budget`` samples at ``samples_per_ray``."""
    want = cfg.sample_budget / max(samples_per_ray, 1.0)
    lo = max(BATCH_QUANTUM, cfg.batch_rays // BUDGET_RANGE)
    n = int(round(want / BATCH_QUANTUM)) * BATCH_QUANTUM
    return int(min(max(n, lo), cfg.batch_rays * BUDGET_RANGE))


#: Bytes per sample slot (ray x segment x sample) of a training step: a floor of what the
#: step's arrays take (docs/constants.md).
BYTES_PER_SAMPLE_SLOT = 64


def training_bytes(batch_rays: int, samples_per_segment: int, segments: int) -> int:
    """A floor of the memory of one training step (see :data:`BYTES_PER_SAMPLE_SLOT`).

    A batch above it cannot fit; one below it may still be too large.
    """
    return batch_rays * samples_per_segment * segments * BYTES_PER_SAMPLE_SLOT


def check_batch(batch_rays: int, model, what: str = '--batch-rays') -> None:
    """Refuse a ray batch whose samples exceed 32-bit indices or the machine's memory.

    ``model`` is the integrator's :class:`~reneus_mi.render.config.ModelConfig` (samples per
    segment, D_re).
    """
    samples = model.sampler.n_coarse + model.sampler.n_fine + 1
    segments = model.render.max_depth + 1
    label = f'{what} {batch_rays} ({samples} samples per segment, {segments} segments)'
    limits.check_index_range(batch_rays * samples * segments, label)
    limits.check_memory(training_bytes(batch_rays, samples, segments), label)


class TrainingError(ReneusError):
    """The run cannot go on (NaN or diverging loss); the last checkpoint is intact."""


@dataclass
class StepStats:
    loss: float
    """The loss: the weighted sum of the terms."""
    terms: dict[str, float]
    """Each term of the loss by name, before its weight (:func:`~reneus_mi.train.losses.loss_dict`)."""
    psnr: float
    learning_rate: float
    inv_s: float
    rays: int
    """Camera rays of the step's batch."""
    rays_per_s: float
    samples: float
    """Field samples (sections) volume rendered in the step."""
    seconds: float

    def record(self) -> dict:
        """The step as a line of log.jsonl: the loss, its terms by name, the rest."""
        values = asdict(self)
        return {'loss': values.pop('loss'), **values.pop('terms'), **values}


class Trainer:
    """One reconstruction: a scene, its dataset, the field and its optimiser."""

    def __init__(self, scene: mi.Scene, dataset: Dataset, cfg: TrainConfig, folder: RunFolder | str, *,
                 frame: FieldFrame | None = None, resume: bool = False):
        """``resume``: continue from the folder's checkpoint, exactly where it was written."""
        integrator = reneus_integrator(scene, 'the scene to train')
        if not 0 <= cfg.validation_view < len(dataset):
            raise ReneusError(f'validation_view={cfg.validation_view}: the dataset has {len(dataset)} views')
        self.scene, self.integrator, self.ds, self.cfg = scene, integrator, dataset, cfg
        self.folder = folder if isinstance(folder, RunFolder) else RunFolder(folder)
        self.container = dataset.container
        self.frame = frame or integrator.frame_of(scene)
        # A refined container may move out of the masks it was drawn with: a margin of
        # pixels around them (outside the glass the photographs show the ambient, as renders do).
        self.pixels = PixelSampler(dataset, cfg.seed, margin=POSE_MARGIN if cfg.refine.pose else 0.0,
                                   config=cfg.pixels)
        self.silhouette = None
        if cfg.refine.pose and cfg.refine.silhouette_weight > 0:
            if not dataset.masks_measured:
                warnings.warn(f'{dataset.root}: the masks are projected from the container mesh, not '
                              'segmented from the photographs: they cannot correct its pose, which '
                              'then follows the refraction alone (weak for flat glass)')
            else:
                self.silhouette = SilhouetteLoss(dataset, self.surroundings.mesh())
        self.iteration = 0
        #: The step of the latest checkpoint this run wrote or resumed from (None: none yet).
        self.saved_iteration: int | None = None
        #: Seconds of training so far (over resumes): how much of a time budget is spent.
        self.elapsed = 0.0
        self.best_loss = float('inf')
        self.batch = cfg.batch_rays
        if resume:
            self._load_checkpoint()
        else:
            self._setup_optimizer()

    def _setup_optimizer(self) -> None:
        cfg = self.cfg
        # What is fitted, in the groups its owners declare: the field's, the board's shading,
        # and the surroundings' that the run refines (held until refine.after).
        refined = self.surroundings.param_groups(cfg.refine)
        self.groups = (self.field.param_groups(cfg.learning_rate)
                       + self.surroundings.model_groups(cfg.learning_rate) + refined)
        self.refined = tuple(name for group in refined for name in group.keys)
        #: What is measured before the first step and not descended after (reported with what is).
        self.measured = (ContainerBow.NAME,) if self.surroundings.bow is not None else ()
        params = mi.traverse(self.scene)
        keys = self.integrator.traverse_keys(params)
        #: The ``mi.traverse`` key of each array fitted, by the integrator's name.
        self.keys = {name: keys[name] for group in self.groups for name in group.keys}
        params.keep(list(self.keys.values()))
        self.params = params
        self.opt = mi.ad.Adam(lr=cfg.learning_rate, params=params)
        # From here on the field computes with the optimiser's variables.
        self.params.update(self.opt)
        # Half-precision networks (CUDA) need loss scaling; an array scale
        # keeps the scaler's first back-off from recompiling the kernels.
        self.scaler = GradScaler(init_scale=mi.Float(2.0 ** 16)) if is_cuda() else None

    @property
    def field(self):
        return self.integrator.field

    @property
    def surroundings(self):
        return self.integrator.bind(self.scene)

    @property
    def names(self) -> dict[str, str]:
        """The integrator's name of each optimiser key (``field.sdf.weights`` -> ``sdf.weights``)."""
        return {key: name for name, key in self.keys.items()}

    def refined_values(self) -> dict:
        """The refined IOR, pose and light as they stand, and what was measured before the first
        step (a host read: for logs and results)."""
        names = self.refined + self.measured
        return self.surroundings.values(names) if names else {}

    def refined_spread(self) -> dict:
        """Per refined value, its standard deviation over the log's rows of the run's last
        fifth (of its steps): how much the estimate still moved at the end, a floor under its
        uncertainty rather than its error (which the photographs alone cannot tell)."""
        rows = []
        if os.path.isfile(self.folder.log):
            with open(self.folder.log) as f:
                rows = [json.loads(line) for line in f if line.strip()]
        rows = [row for row in rows if row.get('iteration', 0) >= 0.8 * self.iteration]
        out = {}
        for name in self.refined:
            values = [row[name] for row in rows if name in row]
            if len(values) > 1:
                out[name] = np.asarray(values, np.float64).std(axis=0).round(6).tolist()
        return out

    # ------------------------------------------------------------ checkpoints
    @property
    def checkpoint_path(self) -> str:
        return self.folder.checkpoint

    def save_checkpoint(self) -> None:
        checkpoint.save(self.checkpoint_path, self.field, self.opt, self.names, iteration=self.iteration,
                        best_loss=self.best_loss, frame=self.frame, container=self.container,
                        scaler=self.scaler, surroundings=self.surroundings.params(), batch=self.batch,
                        elapsed=self.elapsed, pixels=self.pixels.state())
        self.saved_iteration = self.iteration

    def unsaved(self) -> bool:
        """Whether steps were made since the latest checkpoint (or the start)."""
        return self.iteration > (self.saved_iteration or 0)

    def kept(self) -> str:
        """What a failed step leaves to continue from, for its message."""
        if self.saved_iteration is None:
            return f'no checkpoint was written yet ({self.checkpoint_path})'
        return f'the checkpoint of step {self.saved_iteration} ({self.checkpoint_path}) is kept'

    def _load_checkpoint(self) -> None:
        """The field, surroundings, optimiser and counters of the folder's checkpoint."""
        path = self.checkpoint_path
        if not os.path.isfile(path):
            raise ReneusError(f'{path}: no checkpoint to resume from')
        self.integrator.configure(field=load_field(path))
        self.surroundings.load(checkpoint.load_surroundings(path), path)
        self.pixels.load(checkpoint.load_group(path, 'pixels'), path)
        self._setup_optimizer()
        meta = checkpoint.restore(path, self.opt, self.names, self.scaler)
        self.iteration = self.saved_iteration = meta['iteration']
        self.elapsed = meta.get('elapsed', 0.0)
        self.best_loss = meta['best_loss']
        self.batch = meta.get('batch', self.cfg.batch_rays)
        self.folder.repair_log(self.iteration)

    # ------------------------------------------------------------- training
    @property
    def budget(self) -> float:
        """The time budget in seconds (inf: none)."""
        return self.cfg.max_minutes * 60.0 if self.cfg.max_minutes > 0 else float('inf')

    def schedule_step(self) -> int:
        """Where the schedules stand: the step, or under a time budget the share of it
        spent laid over the planned iterations (a 10-minute run decays and sharpens over
        its 10 minutes, however many steps the machine makes of them)."""
        if self.budget == float('inf'):
            return self.iteration
        return min(int(self.elapsed / self.budget * self.cfg.iterations), self.cfg.iterations)

    def step(self) -> StepStats:
        """One optimisation step; raises TrainingError before a bad update is applied."""
        cfg, it, schedule = self.cfg, self.iteration, self.schedule_step()
        start = time.perf_counter()
        batch = self.batch
        ray, target = self.pixels.batch(it, batch)
        self.integrator.begin_step(StepState(step=it, schedule=schedule, cos_anneal_ratio=cfg.cos_anneal_ratio(schedule),
                                             seed=step_seed(cfg.seed, it, JITTER),
                                             refining=self.pixels.uniform_rays() if self.refined else None))
        result = self.integrator.render_rays(self.scene, ray)
        rays = result.color
        if self.pixels.config.rays > 1:
            # A pixel's value: its rays' mean radiance, tone-mapped as the camera's sensor does
            # (and the reach term's inputs per pixel, as the colour it is weighed with).
            per_pixel = self.pixels.pixel_mean
            result = replace(result, color=self.integrator.tonemap(per_pixel(result.L)),
                             nearest=per_pixel(result.nearest), nearest_color=per_pixel(result.nearest_color))
        if self.integrator.model.render.edge_margin > 0.0:
            # Rays through the container's edges keep their colour: no loss, no error to draw by.
            near = self.pixels.pixel_mean(dr.select(result.near_edge, 1.0, 0.0)) > 0.0
            target = dr.select(near, dr.detach(result.color), target)
            # A pair's rays agree with their mean there: no loss either.
            rays = dr.select(self.pixels.per_ray(near), self.pixels.per_ray(dr.detach(result.color)), rays)
        self.pixels.record(result.color, target)
        silhouette = None if self.silhouette is None else self.silhouette(it, self.surroundings.pose)
        pair = (self.pixels.ray(rays, 0), self.pixels.ray(rays, 1)) if self.pixels.config.paired else None
        terms = losses.loss_dict(result, target, cfg, silhouette, pair)
        loss = losses.total(terms)
        mse = losses.mse(result.color, target, self.pixels.uniform_lanes(dr.width(target)))
        samples = dr.sum(result.n_samples)
        # Scheduled, the loss terms are computed in the launch that evaluates
        # the gradients rather than in a forward pass of their own.
        dr.schedule(loss, [term.value for term in terms.values()], mse, samples)
        dr.backward(self.scaler.scale(loss) if self.scaler else loss)
        grads = {key: dr.grad(self.opt[key]) for key in self.opt.keys()}
        # With loss scaling, an overflowing gradient is the scaler's to skip.
        finite = {key: dr.all(dr.isfinite(g)) for key, g in grads.items()} if not self.scaler else {}
        dr.eval(grads, finite)
        # The step's one synchronisation with the device: the loss and the checks.
        value = float(loss[0])
        self._check(value, it)
        for key, ok in finite.items():
            if not bool(ok[0]):
                raise TrainingError(f'step {it}: the gradient of {key!r} is not finite; stopped '
                                    f'before updating; {self.kept()}')
        lr = cfg.learning_rate_at(schedule)
        # Every group follows the run's schedule at its own peak rate, from its start step.
        self.opt.set_learning_rate({self.keys[name]: 0.0 if schedule < group.start else
                                    lr * (group.learning_rate / cfg.learning_rate)
                                    for group in self.groups for name in group.keys})
        if self.scaler:
            self.scaler.step(self.opt)
        else:
            self.opt.step()
        for group in self.groups:
            if group.bounds is not None:
                for name in group.keys:
                    key = self.keys[name]
                    self.opt[key] = dr.clip(self.opt[key], *group.bounds)
        cap, floor = cfg.sharpness_cap(schedule), cfg.sharpness_min(schedule)
        if (cap < math.inf or floor) and 'variance' in self.keys:
            key = self.keys['variance']
            self.opt[key] = dr.clip(self.opt[key], self.field.variance_of(floor) if floor else -math.inf,
                                    self.field.variance_of(cap) if cap < math.inf else math.inf)
        self.params.update(self.opt)
        self.iteration += 1
        self.best_loss = min(self.best_loss, value)
        elapsed = time.perf_counter() - start
        n_samples = float(samples[0])
        if cfg.sample_budget:
            self.batch = next_batch(cfg, n_samples / batch)
        return StepStats(loss=value, terms={name: float(term.value[0]) for name, term in terms.items()},
                         psnr=losses.psnr(float(mse[0])), learning_rate=lr,
                         inv_s=float(self.field.inv_s()[0]), rays=batch, rays_per_s=batch / elapsed,
                         samples=n_samples, seconds=elapsed)

    def fit_media(self) -> None:
        """Beyond the paper: before the field's first step, what the empty container alone shows
        measured from the photographs rendered with it empty (``RefineConfig.media_steps`` says
        why): the walls' thickness (:meth:`search_walls`), the absorption
        (:meth:`fit_absorption`), then a block's faces' bulge (:meth:`search_bow`: a tint not
        yet fitted offsets every pixel, and an L1 loss then no longer sees where the board's
        pattern lies). A run resumed after its first step has done it."""
        refine, surroundings = self.cfg.refine, self.surroundings
        if self.iteration or not refine.media_steps:
            return
        if surroundings.bow is not None and surroundings.backdrop is None:
            raise ReneusError('model.render.bow: the scene has no board under the block, and the faces\' '
                              'bulge is measured from the board seen through it; expected a scene with '
                              "its board (python -m reneus_mi.scene's --board scene) or "
                              '--set model.render.bow=false')
        # Without a board behind it the empty glass shows the uniform light it is lit by,
        # whatever its walls: the field's refinement alone sees them (the specimen through them).
        if refine.wall and surroundings.backdrop is not None:
            self.search_walls()
        if refine.absorption:
            self.fit_absorption()
        if surroundings.bow is not None:
            self.search_bow()

    def fit_absorption(self) -> None:
        """The absorption fitted to uniformly drawn pixels of the empty container, first their
        median, then their mode (``RefineConfig.media_steps``); Adam of its own, its rate
        decaying to 0 (a cosine)."""
        refine = self.cfg.refine
        steps = refine.media_steps
        key = self.keys['container.sigma_a']
        opt = mi.ad.Adam(lr=refine.media_learning_rate)
        opt[key] = self.opt[key]
        (first, last), half = refine.media_scale, steps // 2
        state = self.integrator.state
        try:
            for k in range(steps):
                self.params.update(opt)
                self.integrator.state = StepState(seed=step_seed(self.cfg.seed, k, MEDIA), field=False)
                ray, target = self.pixels.uniform(k, refine.media_rays, MEDIA)
                color = self.integrator.render_rays(self.scene, ray).color
                if k < half:
                    loss = losses.color_l1(color, target)
                else:
                    scale = first * (last / first) ** ((k - half) / max(steps - 1 - half, 1))
                    loss = losses.welsch(color, target, scale)
                dr.backward(loss)
                opt.set_learning_rate(0.5 * refine.media_learning_rate * (1.0 + math.cos(math.pi * k / steps)))
                opt.step()
                opt[key] = dr.clip(opt[key], 0.0, float('inf'))
        finally:
            self.integrator.state = state
        self.opt[key] = opt[key]
        self.params.update(self.opt)

    def search_walls(self) -> None:
        """The walls' thickness where the photographs rendered with the container empty differ
        least from the photographs (the pixels' mean absolute difference at ``wall_rays``
        uniformly drawn pixels): each inner interface's in turn, over :data:`WALL_SEARCH`
        times the stated thickness, then by golden sections about the best. The loss is smooth
        in the thickness but its gradient on a training batch is not (a case's 3 mm glass
        stated 1.5: per batch of 1,024 rays both signs, on 16,384 its true one), so the
        thickness is searched for rather than descended to."""
        key = self.keys[ContainerWalls.NAME]
        walls = self.surroundings.walls
        lo, hi = walls.bounds()
        value = np.array(self.opt[key], np.float64)
        with self._scoring(walls.thickness, value) as score:
            for g, stated in enumerate(walls.stated):
                value[g] = golden_search(score(g), np.clip(stated * np.asarray(WALL_SEARCH), lo, hi))
        self.opt[key] = mi.Float(value)
        self.params.update(self.opt)

    def search_bow(self) -> None:
        """The bulge of each face of a solid block (:mod:`~reneus_mi.render.bow`) where the
        photographs rendered with the block empty differ least from the photographs, as
        :meth:`search_walls` finds the walls: face by face over :data:`BOW_SEARCH` times its
        smaller half-side, then by golden sections about the best, :data:`BOW_PASSES` times
        round (a ray through a side also leaves through the bottom)."""
        bow = self.surroundings.bow
        value = np.zeros(6)
        with self._scoring(bow.bow, value) as score:
            for round in range(BOW_PASSES):
                for k, scale in enumerate(bow.scales()):
                    # Later rounds look a step of the first's grid either side of what it found.
                    grid = BOW_SEARCH if round == 0 else value[k] / scale + np.array([-1.0, 0.0, 1.0]) * BOW_STEP
                    value[k] = golden_search(score(k), scale * np.asarray(grid))
        mi.set_property(bow.bow, mi.Float(value))

    @contextlib.contextmanager
    def _scoring(self, array: mi.Float, value: np.ndarray):
        """Renders of the container without the field (the first step's seeds) at ``wall_rays``
        uniformly drawn pixels; yields ``score``: ``score(k)(x)`` sets ``array`` to ``value``
        with its ``k``-th entry ``x`` and gives the pixels' mean absolute colour difference."""
        ray, target = self.pixels.uniform(0, self.cfg.refine.wall_rays, MEDIA)

        def score(k: int):
            def loss(x: float) -> float:
                trial = value.copy()
                trial[k] = x
                mi.set_property(array, mi.Float(trial))
                with dr.suspend_grad():
                    return float(losses.color_l1(self.integrator.render_rays(self.scene, ray).color, target)[0])
            return loss
        state = self.integrator.state
        try:
            self.integrator.state = StepState(seed=step_seed(self.cfg.seed, 0, MEDIA), field=False)
            yield score
        finally:
            self.integrator.state = state

    def _check(self, value: float, it: int) -> None:
        if not np.isfinite(value):
            raise TrainingError(f'step {it}: the loss is {value}; stopped before updating; {self.kept()}')
        if it >= self.cfg.warm_up and value > self.cfg.divergence_factor * self.best_loss:
            raise TrainingError(f'step {it}: the loss {value:.4g} exceeds {self.cfg.divergence_factor}x '
                                f'its lowest value {self.best_loss:.4g}: diverging; {self.kept()}; '
                                'lower the learning rate (--learning-rate)')

    # ---------------------------------------------------------- validation
    def render_view(self, view: int, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Image (gamma-encoded) and normal map of a view, every ``stride``-th pixel."""
        index = self.pixels.view(view, stride)
        colors, normals = [], []
        with dr.suspend_grad():
            # Stratum midpoints for the render; the step's state comes back whatever happens.
            state, self.integrator.state = self.integrator.state, StepState(step=self.iteration)
            try:
                for first in range(0, dr.width(index), RENDER_CHUNK):
                    chunk = dr.gather(mi.UInt32, index,
                                      dr.arange(mi.UInt32, first, min(first + RENDER_CHUNK, dr.width(index))))
                    r = self.integrator.render_rays(self.scene, self.pixels.rays(chunk))
                    colors.append(np.array(r.color).T)
                    normals.append(np.array(dr.normalize(r.normal)).T)
            finally:
                self.integrator.state = state
        shape = (len(range(0, self.ds.height, stride)), len(range(0, self.ds.width, stride)), 3)
        return np.concatenate(colors).reshape(shape), np.nan_to_num(np.concatenate(normals)).reshape(shape)

    def validate(self) -> None:
        view = self.cfg.validation_view
        image, normals = self.render_view(view)
        both = np.concatenate([image, self.ds.image(view)], axis=1)
        os.makedirs(self.folder.images, exist_ok=True)
        write_image(os.path.join(self.folder.images, f'{self.iteration:06d}.png'), both)
        write_image(os.path.join(self.folder.images, f'{self.iteration:06d}_normal.png'), normals * 0.5 + 0.5)
        try:
            self.write_mesh(os.path.join(self.folder.meshes, f'{self.iteration:06d}.ply'), resolution=64)
        except NoSurfaceError as e:
            warnings.warn(f'step {self.iteration}: no mesh snapshot ({e}); training goes on')

    def write_container(self, path: str) -> str:
        """The container mesh at its refined pose, in world coordinates, with its optics."""
        write_mesh(self.surroundings.posed_mesh(), path)
        return path

    def mesh_resolution(self) -> int:
        """The final mesh's grid over the container's box: ``mesh_resolution``, or the field's
        finest detail where that is finer (a hash grid fitted to large photographs), as long as
        the part of it that holds the surface has at most :data:`MAX_AUTO_MESH_POINTS`."""
        resolution = self.cfg.mesh_resolution
        detail = self.field.detail()
        if detail:
            lo, hi = self.frame.field_box()
            inner_lo, inner_hi = surface_box(self.field, lo, hi)
            share = float(np.prod((inner_hi - inner_lo) / (hi - lo)))
            need = int(np.ceil(float(np.max(hi - lo)) / detail))
            resolution = max(resolution, min(need, int(MAX_AUTO_MESH_POINTS ** (1 / 3) / share ** (1 / 3))))
        return resolution

    def write_mesh(self, path: str, resolution: int | None = None):
        mesh = field_mesh(self.field, self.frame, resolution or self.mesh_resolution(),
                          self.cfg.postprocess, self.container)
        write_mesh(mesh, path)
        return mesh

    def write_glb(self, mesh: trimesh.Trimesh, path: str) -> dict:
        """``mesh`` (world) as a web viewer's glTF: coloured by the field (:func:`field_colors`),
        in metres with y up where the dataset says its units and the table's up (a capture);
        returns what result.json says of it."""
        board, units = self.ds.board, self.ds.units
        colors = field_colors(self.field, self.frame, mesh.vertices, self.integrator.model.render.gamma)
        if board is None:
            to_gltf = gltf_from_world(units)
            frame = "the dataset's world" + (f', in metres (from {units})' if units else '')
        else:
            # The board's z points into the table.
            to_gltf = gltf_from_world(units, up=-board.to_world[:3, 2], right=board.to_world[:3, 0])
            frame = "glTF's: metres, x, y, z = the board's x, -z (up), y"
        write_glb(mesh, colors, path, to_gltf)
        return {'path': path, 'frame': frame, 'colors': 'the radiance seen along the normal, gamma-encoded'}

    # ----------------------------------------------------------------- loop
    def run(self, progress: bool = True) -> dict:
        """Train to ``cfg.iterations`` (or through the time budget), checkpointing and validating
        on the way."""
        cfg = self.cfg
        os.makedirs(self.folder.path, exist_ok=True)
        start, psnrs = time.perf_counter(), []
        timed = self.budget != float('inf')
        turn = time.perf_counter()
        self.fit_media()
        self.elapsed += time.perf_counter() - turn
        bar = tqdm(total=cfg.iterations, initial=self.iteration, disable=not progress or timed,
                   unit='it', dynamic_ncols=True)
        try:
            # A run from its first step starts its log anew: lines of an attempt killed before
            # its first checkpoint belong to no step of this one.
            with open(self.folder.log, 'a' if self.iteration else 'w') as log, \
                    interrupt.deferred(unsaved=self.unsaved) as interrupted:
                while self.elapsed < self.budget if timed else self.iteration < cfg.iterations:
                    if interrupted():
                        raise KeyboardInterrupt
                    turn = time.perf_counter()
                    stats = self.step()
                    psnrs = (psnrs + [stats.psnr])[-100:]
                    if self.iteration % cfg.log_every == 0:
                        log.write(json.dumps({'iteration': self.iteration, 'schedule': self.schedule_step(),
                                              **stats.record(),
                                              **self.refined_values()}) + '\n')
                        log.flush()
                    bar.update(1)
                    bar.set_postfix(loss=f'{stats.loss:.4f}', psnr=f'{stats.psnr:.2f}',
                                    rays_s=f'{stats.rays_per_s:.0f}', refresh=False)
                    if cfg.checkpoint_every and self.iteration % cfg.checkpoint_every == 0:
                        self.save_checkpoint()
                    if cfg.validate_every and self.iteration % cfg.validate_every == 0:
                        self.validate()
                    self.elapsed += time.perf_counter() - turn
        except KeyboardInterrupt:
            bar.close()
            if self.unsaved():
                self.save_checkpoint()
            raise
        bar.close()
        self.save_checkpoint()
        mesh_path = self.folder.mesh
        result = {'iterations': self.iteration, 'seconds': time.perf_counter() - start,
                  'psnr': float(np.mean(psnrs)) if psnrs else float('nan'), 'mesh': mesh_path,
                  'stopped_by_budget': timed}
        # The mesh's coordinates are the dataset's world: its units and frame where it states them.
        result.update({key: value for key, value in (('units', self.ds.units), ('frame', self.ds.frame)) if value})
        if self.ds.gt_mesh:
            result['ground_truth'] = self.ds.gt_mesh
        if self.refined or self.measured:
            result['refined'] = self.refined_values()
            result['refined_spread'] = self.refined_spread()
        if cfg.refine.pose or cfg.refine.wall or self.surroundings.bow is not None:
            result['container'] = self.write_container(self.folder.container)
        try:
            mesh = self.write_mesh(mesh_path)
            result['components'] = components(mesh)
            result['glb'] = self.write_glb(mesh, self.folder.web_mesh)
        except NoSurfaceError as e:
            # A run never ends without its mesh file: an empty one, and the reason.
            write_mesh(trimesh.Trimesh(), mesh_path)
            result['failure'] = (f'{e}; {mesh_path} is empty; the run can go on: --resume with more '
                                 '--iterations (or a lower --trans-weight)')
        return result
