"""Fitting the ``reneus`` integrator's field to posed photographs (Sec. 3.4).

Each step draws ``batch_rays`` pixels at random among the container-mask
pixels of all views, traces them with :meth:`ReNeuSIntegrator.trace`, and
takes one Adam step on L = L_color + λ1 L_trans + λ2 L_reg. The run lives in
one output folder::

    config.json       the TrainConfig and where the scene and data came from
    log.jsonl         one line per step: losses, PSNR, learning rate, s, rays/s
    checkpoint.npz    the latest checkpoint (atomic; --resume continues from it)
    images/           validation renders (image | photograph) and normal maps
    meshes/           mesh snapshots (64^3) at validation steps
    mesh.ply          the final mesh, in the dataset's world coordinates
"""
from __future__ import annotations

import json
import os
import time
import warnings
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
from drjit.opt import GradScaler

from reneus_mi import checkpoint, guards, losses
from reneus_mi.config import TrainConfig
from reneus_mi.data import Dataset
from reneus_mi.fields import load_field
from reneus_mi.extract import field_mesh, write_mesh
from reneus_mi.mesh import NoSurfaceError
from reneus_mi.variant import is_cuda
from reneus_mi.render import write_image

#: Rays per kernel launch when rendering a whole view.
RENDER_CHUNK = 1 << 14


class TrainingError(RuntimeError):
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
    rays_per_s: float


class Trainer:
    """One reconstruction: a scene, its dataset, the field and its optimiser."""

    def __init__(self, scene: mi.Scene, dataset: Dataset, cfg: TrainConfig, out_dir: str):
        integrator = scene.integrator()
        if not hasattr(integrator, 'trace'):
            raise ValueError(f'the scene\'s integrator is {type(integrator).__name__}; expected '
                             '<integrator type="reneus">')
        self.scene, self.integrator, self.ds, self.cfg, self.out = scene, integrator, dataset, cfg, out_dir
        if not 0 <= cfg.validation_view < len(dataset):
            raise ValueError(f'validation_view={cfg.validation_view}: the dataset has {len(dataset)} views')
        # Flat indices (view, y, x) of the pixels inside the container mask M_in.
        self.pixels = np.flatnonzero(dataset.masks.reshape(-1))
        if len(self.pixels) == 0:
            raise ValueError(f'{dataset.root}: no view sees the container (all masks are empty)')
        self.colors = dataset.images.reshape(-1, 3)
        self.rng = np.random.default_rng(cfg.seed)
        self.iteration = 0
        self.best_loss = float('inf')
        self.opt = mi.ad.Adam(lr=cfg.learning_rate, params=self.field.params())
        # Half-precision networks (CUDA) need loss scaling; an array scale
        # keeps the scaler's first back-off from recompiling the kernels.
        self.scaler = GradScaler(init_scale=mi.Float(2.0 ** 16)) if is_cuda() else None

    @property
    def field(self):
        return self.integrator.field

    # ------------------------------------------------------------ checkpoints
    @property
    def checkpoint_path(self) -> str:
        return os.path.join(self.out, 'checkpoint.npz')

    def save_checkpoint(self) -> None:
        # The field holds the weights of the last step's forward pass; the
        # optimiser holds the updated ones, which the checkpoint must carry.
        with dr.suspend_grad():
            self.field.set_params(self.opt)
        checkpoint.save(self.checkpoint_path, self.field, self.opt, iteration=self.iteration,
                        rng=self.rng, best_loss=self.best_loss, frame=self.frame)

    def resume(self) -> None:
        """Continue from the output folder's checkpoint, exactly where it was written."""
        path = self.checkpoint_path
        if not os.path.isfile(path):
            raise ValueError(f'{path}: no checkpoint to resume from')
        self.integrator.field = load_field(path)
        self.opt = mi.ad.Adam(lr=self.cfg.learning_rate, params=self.field.params())
        meta = checkpoint.restore(path, self.opt)
        self.iteration = meta['iteration']
        self.rng.bit_generator.state = meta['rng']
        self.best_loss = meta['best_loss']
        guards.repair_log(os.path.join(self.out, 'log.jsonl'), self.iteration)

    # ------------------------------------------------------------- training
    def batch(self):
        """Random camera rays inside the masks, their target colours and jitters."""
        n = self.cfg.batch_rays
        index = self.pixels[self.rng.integers(0, len(self.pixels), n)]
        h, w = self.ds.height, self.ds.width
        view, rest = np.divmod(index, h * w)
        y, x = np.divmod(rest, w)
        o, d = self.ds.rays(view, np.stack([x, y], axis=1))
        target = self.colors[index]
        jitter = self.rng.random(n)
        return _ray(o, d), mi.Color3f(*target.T.astype(np.float32)), mi.Float(jitter.astype(np.float32))

    def step(self) -> StepStats:
        """One optimisation step; raises TrainingError before a bad update is applied."""
        cfg, it = self.cfg, self.iteration
        start = time.perf_counter()
        # An interrupted step must leave the batch stream where the checkpoint expects it.
        rng_state = self.rng.bit_generator.state
        try:
            return self._step(cfg, it, start)
        except BaseException:
            self.rng.bit_generator.state = rng_state
            raise

    def _step(self, cfg, it, start) -> StepStats:
        ray, target, jitter = self.batch()
        self.field.set_params(self.opt)
        result = self.integrator.trace(self.scene, ray, jitter=jitter,
                                       cos_anneal_ratio=cfg.cos_anneal_ratio(it))
        pred = self.integrator.tonemap(result.L)
        l_color = losses.color_l1(pred, target)
        l_trans = losses.transmittance_sparsity(result.sparsity)
        l_eik = losses.eikonal(result.eikonal, result.n_samples)
        loss = l_color + cfg.trans_weight * l_trans + cfg.eikonal_weight * l_eik
        # Scheduled, the loss terms are computed in the launch that evaluates
        # the gradients rather than in a forward pass of their own.
        dr.schedule(loss, l_color, l_trans, l_eik, pred)
        dr.backward(self.scaler.scale(loss) if self.scaler else loss)
        grads = [dr.grad(self.opt[key]) for key in self.opt.keys()]
        dr.eval(grads)
        self._check(float(loss[0]), it)
        # With loss scaling, an overflowing gradient is the scaler's to skip.
        for key, grad in zip(self.opt.keys(), grads):
            if not self.scaler and not dr.all(dr.isfinite(grad)):
                raise TrainingError(f'step {it}: the gradient of {key!r} is not finite; stopped '
                                    f'before updating, the last checkpoint ({self.checkpoint_path}) is intact')
        lr = cfg.learning_rate_at(it)
        self.opt.set_learning_rate(lr)
        if self.scaler:
            self.scaler.step(self.opt)
        else:
            self.opt.step()
        self.iteration += 1
        value = float(loss[0])
        self.best_loss = min(self.best_loss, value)
        dr.sync_thread()
        elapsed = time.perf_counter() - start
        return StepStats(loss=value, color=float(l_color[0]), trans=float(l_trans[0]),
                         eikonal=float(l_eik[0]), psnr=losses.psnr(pred, target), learning_rate=lr,
                         inv_s=float(self.field.inv_s()[0]), rays_per_s=cfg.batch_rays / elapsed)

    def _check(self, value: float, it: int) -> None:
        if not np.isfinite(value):
            raise TrainingError(f'step {it}: the loss is {value}; stopped before updating, the '
                                f'last checkpoint ({self.checkpoint_path}) is intact')
        if it >= self.cfg.warm_up and value > self.cfg.divergence_factor * self.best_loss:
            raise TrainingError(f'step {it}: the loss {value:.4g} exceeds {self.cfg.divergence_factor}x '
                                f'its lowest value {self.best_loss:.4g}: diverging; lower the learning '
                                f'rate; the last checkpoint ({self.checkpoint_path}) is intact')

    # ---------------------------------------------------------- validation
    def render_view(self, view: int, scale: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Image (gamma-encoded) and normal map of a view, every ``scale``-th pixel."""
        h, w = self.ds.height, self.ds.width
        ys, xs = np.mgrid[0:h:scale, 0:w:scale]
        px = np.stack([xs.ravel(), ys.ravel()], axis=1)
        o, d = self.ds.rays(np.full(len(px), view), px)
        colors, normals = [], []
        with dr.suspend_grad():
            self.field.set_params(self.opt)
            for s in range(0, len(px), RENDER_CHUNK):
                r = self.integrator.trace(self.scene, _ray(o[s:s + RENDER_CHUNK], d[s:s + RENDER_CHUNK]))
                colors.append(np.array(self.integrator.tonemap(r.L)).T)
                normals.append(np.array(dr.normalize(r.normal)).T)
        shape = ys.shape + (3,)
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

    @property
    def frame(self) -> dict:
        """The field's frame and the container, as checkpoints record them."""
        c, r = np.array(self.integrator.field_center), self.integrator.field_scale
        bbox = self.scene.bbox()
        # Without a container (NeuS on box-free data) the field's sphere bounds the mesh.
        lo, hi = (np.array(bbox.min), np.array(bbox.max)) if bbox.valid() else (c - r, c + r)
        return {'center': c.tolist(), 'scale': r, 'lo': lo.tolist(), 'hi': hi.tolist(),
                'container': self.ds.container}

    def write_mesh(self, path: str, resolution: int | None = None):
        with dr.suspend_grad():
            self.field.set_params(self.opt)
        mesh = field_mesh(self.field, self.frame, resolution or self.cfg.mesh_resolution, self.cfg.postprocess)
        write_mesh(mesh, path)
        return mesh

    # ----------------------------------------------------------------- loop
    def run(self, progress: bool = True) -> dict:
        """Train to ``cfg.iterations``, checkpointing and validating on the way."""
        from tqdm import tqdm
        cfg = self.cfg
        os.makedirs(self.out, exist_ok=True)
        log_path = os.path.join(self.out, 'log.jsonl')
        start, psnrs = time.perf_counter(), []
        bar = tqdm(total=cfg.iterations, initial=self.iteration, disable=not progress,
                   unit='it', dynamic_ncols=True)
        try:
            with open(log_path, 'a') as log:
                while self.iteration < cfg.iterations:
                    stats = self.step()
                    psnrs = (psnrs + [stats.psnr])[-100:]
                    log.write(json.dumps({'iteration': self.iteration, **stats.__dict__}) + '\n')
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
        try:
            self.write_mesh(mesh_path)
        except NoSurfaceError as e:
            raise TrainingError(f'{e}: no surface yet after {self.iteration} steps; the checkpoint '
                                f'{self.checkpoint_path} is saved: continue with --resume and more '
                                '--iterations') from None
        return {'iterations': self.iteration, 'seconds': time.perf_counter() - start,
                'psnr': float(np.mean(psnrs)) if psnrs else float('nan'), 'mesh': mesh_path}


def _ray(o: np.ndarray, d: np.ndarray) -> mi.Ray3f:
    o, d = o.astype(np.float32), d.astype(np.float32)
    return mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T))

