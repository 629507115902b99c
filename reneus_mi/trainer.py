"""Fitting the ``reneus`` integrator's field to posed photographs (Sec. 3.4).

Each step draws ``batch_rays`` pixels at random among the container-mask
pixels of all views (:class:`~reneus_mi.pixel_sampler.PixelSampler`; under a
``sample_budget`` the batch follows the samples per ray), renders them with
:meth:`ReNeuSIntegrator.render_rays` (what ``mi.render`` runs too), and takes
one ``mi.ad.Adam`` step on L = L_color + λ1 L_trans + λ2 L_reg (+ the
container's silhouette term while its pose is refined). The parameters are
``mi.traverse(scene)``'s view of the field's own arrays, and of the IOR, pose
and light a run refines (:mod:`reneus_mi.surroundings`), updated with
``params.update(opt)``, as in a hand-written Mitsuba optimisation loop.
The run lives in one output folder::

    config.json       the whole configuration and where the scene and data came from
    log.jsonl         one line every log_every steps: losses, PSNR, learning rate, s, rays/s,
                      and the refined IOR, pose and light
    container_refined.ply   the container at its refined pose (with refine_pose)
    checkpoint.npz    the latest checkpoint (atomic; --resume continues from it)
    images/           validation renders (image | photograph) and normal maps
    meshes/           mesh snapshots (64^3) at validation steps
    mesh.ply          the final mesh, in the dataset's world coordinates
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import threading
import time
import warnings
from dataclasses import asdict, dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh
from drjit.opt import GradScaler

from reneus_mi import checkpoint, guards, losses
from reneus_mi.config import TrainConfig
from reneus_mi.data import Dataset
from reneus_mi.errors import NoSurfaceError, ReneusError
from reneus_mi.extract import field_mesh, write_mesh
from reneus_mi.fields import load_field
from reneus_mi.frame import FieldFrame
from reneus_mi.mesh import components
from reneus_mi.pixel_sampler import JITTER, PixelSampler, step_seed
from reneus_mi.render import write_image
from reneus_mi.variant import is_cuda

#: Rays per kernel launch when rendering a whole view.
RENDER_CHUNK = 1 << 14
#: Mask margin while the container's pose is refined, as a fraction of the container's size in
#: the image: covers the 2-5 % pose errors a calibration leaves.
POSE_MARGIN = 0.1


#: Batches under a sample budget are multiples of this many rays, between the configured
#: batch / BUDGET_RANGE and batch x BUDGET_RANGE.
BATCH_QUANTUM, BUDGET_RANGE = 256, 8


def next_batch(cfg: TrainConfig, samples_per_ray: float) -> int:
    """The batch that renders about ``cfg.sample_budget`` samples at ``samples_per_ray``."""
    want = cfg.sample_budget / max(samples_per_ray, 1.0)
    lo = max(BATCH_QUANTUM, cfg.batch_rays // BUDGET_RANGE)
    n = int(round(want / BATCH_QUANTUM)) * BATCH_QUANTUM
    return int(min(max(n, lo), cfg.batch_rays * BUDGET_RANGE))


class TrainingError(ReneusError):
    """The run cannot go on (NaN or diverging loss); the last checkpoint is intact."""


@dataclass
class StepStats:
    loss: float
    color: float
    trans: float
    eikonal: float
    psnr: float
    learning_rate: float
    inv_s: float
    rays: int
    """Camera rays of the step's batch."""
    rays_per_s: float
    samples: float
    """Field samples (sections) volume rendered in the step."""
    seconds: float


def refined_rates(cfg: TrainConfig) -> dict[str, float]:
    """The integrator's parameters (besides the field's) that a run refines, with their peak
    learning rates."""
    rates = {'container.eta': cfg.ior_learning_rate} if cfg.refine_ior else {}
    if cfg.refine_pose:
        rates.update(dict.fromkeys(('container.translation', 'container.rotation', 'container.log_scale'),
                                   cfg.pose_learning_rate))
    if cfg.refine_light != 'none':
        rates['light.radiance' if cfg.refine_light == 'ambient' else 'light.sh'] = cfg.light_learning_rate
    return rates


def trainable_parameters(scene: mi.Scene, cfg: TrainConfig | None = None) -> mi.SceneParameters:
    """``mi.traverse(scene)`` kept to what is fitted: the field's own arrays and the
    surroundings that ``cfg`` refines."""
    integrator = scene.integrator()
    integrator.bind(scene)
    params = mi.traverse(scene)
    named = integrator.params()
    own = [id(v) for v in integrator.field.params().values()]
    own += [id(named[n]) for n in (refined_rates(cfg) if cfg else {})]
    # The raw entries: reading through params[k] would mark every key for update.
    params.keep([k for k, (value, *_) in params.properties.items() if id(value) in own])
    return params


class Trainer:
    """One reconstruction: a scene, its dataset, the field and its optimiser."""

    def __init__(self, scene: mi.Scene, dataset: Dataset, cfg: TrainConfig, out_dir: str, *,
                 frame: FieldFrame | None = None):
        integrator = scene.integrator()
        if not hasattr(integrator, 'render_rays'):
            raise ReneusError(f'the scene\'s integrator is {type(integrator).__name__}; expected '
                              '<integrator type="reneus">')
        if not 0 <= cfg.validation_view < len(dataset):
            raise ReneusError(f'validation_view={cfg.validation_view}: the dataset has {len(dataset)} views')
        self.scene, self.integrator, self.ds, self.cfg, self.out = scene, integrator, dataset, cfg, out_dir
        self.container = dataset.container
        self.frame = frame or integrator.frame_of(scene)
        # A refined container may move out of the masks it was drawn with: a margin of
        # pixels around them (outside the glass the photographs show the ambient, as renders do).
        self.pixels = PixelSampler(dataset, cfg.seed, margin=POSE_MARGIN if cfg.refine_pose else 0.0)
        self.silhouette = None
        if cfg.refine_pose and cfg.silhouette_weight > 0:
            if not dataset.masks_measured:
                warnings.warn(f'{dataset.root}: the masks are projected from the container mesh, not '
                              'segmented from the photographs: they cannot correct its pose, which '
                              'then follows the refraction alone (weak for flat glass)')
            else:
                from reneus_mi.silhouette import SilhouetteLoss
                self.silhouette = SilhouetteLoss(dataset, self.surroundings.mesh())
        self.iteration = 0
        self.best_loss = float('inf')
        self.batch = cfg.batch_rays
        self._setup_optimizer()

    def _setup_optimizer(self) -> None:
        cfg = self.cfg
        self.params = trainable_parameters(self.scene, cfg)
        self.opt = mi.ad.Adam(lr=cfg.learning_rate, params=self.params)
        # From here on the field computes with the optimiser's variables.
        self.params.update(self.opt)
        # Learning rates relative to the field's peak: the field's groups scale it, the
        # surroundings have their own (they follow the same schedule).
        own = refined_rates(cfg)
        self._lr_scale = {key: own[name] / cfg.learning_rate if name in own
                          else self.field.lr_scale().get(name, 1.0)
                          for key, name in ((k, self._name(k)) for k in self.opt.keys())}
        self._refined = {self._name(k): k for k in self.opt.keys() if self._name(k) in own}
        # Half-precision networks (CUDA) need loss scaling; an array scale
        # keeps the scaler's first back-off from recompiling the kernels.
        self.scaler = GradScaler(init_scale=mi.Float(2.0 ** 16)) if is_cuda() else None

    @property
    def field(self):
        return self.integrator.field

    @property
    def surroundings(self):
        return self.integrator.bind(self.scene)

    def _name(self, key: str) -> str:
        """The integrator's name of a ``mi.traverse`` key (``field.sdf.weights`` -> ``sdf.weights``)."""
        names = {id(v): k for k, v in self.integrator.params().items()}
        return names[id(self.params.properties[key][0])]

    def refined_values(self) -> dict:
        """The refined IOR, pose and light as they stand (a host read: for logs and results)."""
        if not self._refined:
            return {}
        values = self.surroundings.values()
        derived = {'container.log_scale': 'container.scale', 'light.sh': 'light.mean'}
        keep = set(self._refined) | {derived[k] for k in self._refined if k in derived}
        return {k: v for k, v in values.items() if k in keep}

    # ------------------------------------------------------------ checkpoints
    @property
    def checkpoint_path(self) -> str:
        return os.path.join(self.out, 'checkpoint.npz')

    def save_checkpoint(self) -> None:
        names = {key: self._name(key) for key in self.opt.keys()}
        checkpoint.save(self.checkpoint_path, self.field, self.opt, names, iteration=self.iteration,
                        best_loss=self.best_loss, frame=self.frame, container=self.container,
                        scaler=self.scaler, surroundings=self.surroundings.params(), batch=self.batch)

    def resume(self) -> None:
        """Continue from the output folder's checkpoint, exactly where it was written."""
        path = self.checkpoint_path
        if not os.path.isfile(path):
            raise ReneusError(f'{path}: no checkpoint to resume from')
        self.integrator.configure(field=load_field(path))
        self.surroundings.load(checkpoint.load_surroundings(path), path)
        self._setup_optimizer()
        names = {key: self._name(key) for key in self.opt.keys()}
        meta = checkpoint.restore(path, self.opt, names, self.scaler)
        self.iteration = meta['iteration']
        self.best_loss = meta['best_loss']
        self.batch = meta.get('batch', self.cfg.batch_rays)
        guards.repair_log(os.path.join(self.out, 'log.jsonl'), self.iteration)

    # ------------------------------------------------------------- training
    def step(self) -> StepStats:
        """One optimisation step; raises TrainingError before a bad update is applied."""
        from reneus_mi.plugins.reneus import StepState
        cfg, it = self.cfg, self.iteration
        start = time.perf_counter()
        self.integrator.begin_step(StepState(step=it, cos_anneal_ratio=cfg.cos_anneal_ratio(it),
                                             seed=step_seed(cfg.seed, it, JITTER)))
        batch = self.batch
        ray, target = self.pixels.batch(it, batch)
        result = self.integrator.render_rays(self.scene, ray)
        l_color = losses.color_l1(result.color, target)
        l_trans = losses.transmittance_sparsity(result.sparsity)
        l_eik = losses.eikonal(result.eikonal, result.n_samples)
        loss = l_color + cfg.trans_weight * l_trans + cfg.eikonal_weight * l_eik
        if self.silhouette is not None:
            loss += cfg.silhouette_weight * self.silhouette(it, self.surroundings.pose)
        mse = losses.mean(dr.square(dr.detach(result.color) - target))
        samples = dr.sum(result.n_samples)
        # Scheduled, the loss terms are computed in the launch that evaluates
        # the gradients rather than in a forward pass of their own.
        dr.schedule(loss, l_color, l_trans, l_eik, mse, samples)
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
                                    f'before updating, the last checkpoint ({self.checkpoint_path}) is intact')
        lr = cfg.learning_rate_at(it)
        held = set(self._refined.values()) if it < cfg.refine_after else set()
        self.opt.set_learning_rate({key: 0.0 if key in held else lr * s for key, s in self._lr_scale.items()})
        if self.scaler:
            self.scaler.step(self.opt)
        else:
            self.opt.step()
        if 'container.eta' in self._refined:
            key = self._refined['container.eta']
            self.opt[key] = dr.clip(self.opt[key], *cfg.ior_range)
        self.params.update(self.opt)
        self.iteration += 1
        self.best_loss = min(self.best_loss, value)
        elapsed = time.perf_counter() - start
        m = float(mse[0])
        n_samples = float(samples[0])
        if cfg.sample_budget:
            self.batch = next_batch(cfg, n_samples / batch)
        return StepStats(loss=value, color=float(l_color[0]), trans=float(l_trans[0]),
                         eikonal=float(l_eik[0]), psnr=float('inf') if m == 0 else -10.0 * np.log10(m),
                         learning_rate=lr, inv_s=float(self.field.inv_s()[0]), rays=batch,
                         rays_per_s=batch / elapsed, samples=n_samples, seconds=elapsed)

    def _check(self, value: float, it: int) -> None:
        if not np.isfinite(value):
            raise TrainingError(f'step {it}: the loss is {value}; stopped before updating, the '
                                f'last checkpoint ({self.checkpoint_path}) is intact')
        if it >= self.cfg.warm_up and value > self.cfg.divergence_factor * self.best_loss:
            raise TrainingError(f'step {it}: the loss {value:.4g} exceeds {self.cfg.divergence_factor}x '
                                f'its lowest value {self.best_loss:.4g}: diverging; lower the learning '
                                f'rate; the last checkpoint ({self.checkpoint_path}) is intact')

    # ---------------------------------------------------------- validation
    def render_view(self, view: int, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Image (gamma-encoded) and normal map of a view, every ``stride``-th pixel."""
        from reneus_mi.plugins.reneus import StepState
        index = self.pixels.view(view, stride)
        colors, normals = [], []
        with dr.suspend_grad():
            state, self.integrator.state = self.integrator.state, StepState(step=self.iteration)
            for s in range(0, dr.width(index), RENDER_CHUNK):
                chunk = dr.gather(mi.UInt32, index, dr.arange(mi.UInt32, s, min(s + RENDER_CHUNK, dr.width(index))))
                r = self.integrator.render_rays(self.scene, self.pixels.rays(chunk))
                colors.append(np.array(r.color).T)
                normals.append(np.array(dr.normalize(r.normal)).T)
            self.integrator.state = state
        shape = (len(range(0, self.ds.height, stride)), len(range(0, self.ds.width, stride)), 3)
        return np.concatenate(colors).reshape(shape), np.nan_to_num(np.concatenate(normals)).reshape(shape)

    def validate(self) -> None:
        view = self.cfg.validation_view
        image, normals = self.render_view(view)
        both = np.concatenate([image, self.ds.images[view]], axis=1)
        os.makedirs(os.path.join(self.out, 'images'), exist_ok=True)
        write_image(both, os.path.join(self.out, 'images', f'{self.iteration:06d}.png'))
        write_image(normals * 0.5 + 0.5, os.path.join(self.out, 'images', f'{self.iteration:06d}_normal.png'))
        try:
            self.write_mesh(os.path.join(self.out, 'meshes', f'{self.iteration:06d}.ply'), resolution=64)
        except NoSurfaceError as e:
            warnings.warn(f'step {self.iteration}: no mesh snapshot ({e}); training goes on')

    def write_container(self, path: str) -> str:
        """The container mesh at its refined pose, in world coordinates."""
        mesh = self.surroundings.mesh()
        mesh.apply_transform(self.surroundings.pose.matrix())
        write_mesh(mesh, path)
        return path

    def write_mesh(self, path: str, resolution: int | None = None):
        mesh = field_mesh(self.field, self.frame, resolution or self.cfg.mesh_resolution,
                          self.cfg.postprocess, self.container)
        write_mesh(mesh, path)
        return mesh

    # ----------------------------------------------------------------- loop
    def run(self, progress: bool = True) -> dict:
        """Train to ``cfg.iterations`` (or the time budget), checkpointing and validating on the way."""
        from tqdm import tqdm
        cfg = self.cfg
        os.makedirs(self.out, exist_ok=True)
        log_path = os.path.join(self.out, 'log.jsonl')
        start, psnrs = time.perf_counter(), []
        budget = cfg.max_minutes * 60.0 if cfg.max_minutes > 0 else float('inf')
        bar = tqdm(total=cfg.iterations, initial=self.iteration, disable=not progress,
                   unit='it', dynamic_ncols=True)
        try:
            with open(log_path, 'a') as log, _deferred_interrupt() as interrupted:
                while self.iteration < cfg.iterations and time.perf_counter() - start < budget:
                    if interrupted():
                        raise KeyboardInterrupt
                    stats = self.step()
                    psnrs = (psnrs + [stats.psnr])[-100:]
                    if self.iteration % cfg.log_every == 0:
                        log.write(json.dumps({'iteration': self.iteration, **asdict(stats),
                                              **self.refined_values()}) + '\n')
                        log.flush()
                    bar.update(1)
                    bar.set_postfix(loss=f'{stats.loss:.4f}', psnr=f'{stats.psnr:.2f}',
                                    rays_s=f'{stats.rays_per_s:.0f}', refresh=False)
                    if cfg.checkpoint_every and self.iteration % cfg.checkpoint_every == 0:
                        self.save_checkpoint()
                    if cfg.validate_every and self.iteration % cfg.validate_every == 0:
                        self.validate()
        except KeyboardInterrupt:
            self.save_checkpoint()
            bar.close()
            raise
        bar.close()
        self.save_checkpoint()
        mesh_path = os.path.join(self.out, 'mesh.ply')
        result = {'iterations': self.iteration, 'seconds': time.perf_counter() - start,
                  'psnr': float(np.mean(psnrs)) if psnrs else float('nan'), 'mesh': mesh_path,
                  'stopped_by_budget': self.iteration < cfg.iterations}
        if self._refined:
            result['refined'] = self.refined_values()
        if cfg.refine_pose:
            result['container'] = self.write_container(os.path.join(self.out, 'container_refined.ply'))
        try:
            result['components'] = components(self.write_mesh(mesh_path))
        except NoSurfaceError as e:
            # A run never ends without its mesh file: an empty one, and the reason.
            write_mesh(trimesh.Trimesh(), mesh_path)
            result['failure'] = (f'{e}; {mesh_path} is empty; the run can go on: --resume with more '
                                 '--iterations (or a lower --trans-weight)')
        return result


@contextlib.contextmanager
def _deferred_interrupt():
    """Ctrl-C ends the loop between steps, never inside one (a checkpoint then holds a whole step)."""
    flag = []
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    previous = signal.signal(signal.SIGINT, lambda *_: flag.append(True))
    try:
        yield lambda: bool(flag)
    finally:
        signal.signal(signal.SIGINT, previous)
