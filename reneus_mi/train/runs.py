"""Runs: one reconstruction in one folder, and many of them.

A :class:`RunSpec` is everything a run is made of: the scene (container,
light), the dataset and the whole :class:`~reneus_mi.config.ReconstructionConfig`.
:func:`run` trains one in its folder (:class:`~reneus_mi.train.run_folder.RunFolder`)
and writes ``config.json`` (the spec, which rebuilds the run: :func:`read_spec`)
and ``result.json``; :func:`run_many` goes through a collection by the state of
each folder, skipping finished runs and resuming killed ones, so that a batch
of specimens (or a benchmark table) can be interrupted and started again at no
cost.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

from reneus_mi.config import ReconstructionConfig, from_dict, to_dict
from reneus_mi.errors import ReneusError
from reneus_mi.io import check_npz_file
from reneus_mi.train.run_folder import RunFolder


@dataclass
class RunSpec:
    scene: str
    """The scene XML: container, ambient light and the reneus integrator."""
    data: str
    """The dataset folder (photographs, cameras, masks, container)."""
    config: ReconstructionConfig
    """The model rendered (overrides the scene's integrator settings) and its training."""
    preset: str = ''
    """The preset the configuration started from, for the record."""
    mesh_bounds: tuple | None = None
    """World box (lo, hi) to mesh in, instead of the container's (e.g. box-free data)."""
    data_fingerprint: dict | None = None
    """Views, image size and a digest of the cameras of the dataset the run was started on:
    a resumed run checks that a dataset given anew (moved) is the same one."""

    def to_dict(self) -> dict:
        return {'scene': os.path.abspath(self.scene), 'data': os.path.abspath(self.data),
                'preset': self.preset, 'mesh_bounds': self.mesh_bounds,
                'data_fingerprint': self.data_fingerprint, **to_dict(self.config)}

    @staticmethod
    def from_dict(d: dict, where: str) -> 'RunSpec':
        d = dict(d)
        try:
            scene, data = d.pop('scene'), d.pop('data')
        except KeyError as e:
            raise ReneusError(f'{where}: no {e.args[0]!r} entry; expected scene, data, model, train') from None
        preset, bounds, fingerprint = d.pop('preset', ''), d.pop('mesh_bounds', None), d.pop('data_fingerprint', None)
        try:
            config = from_dict(ReconstructionConfig, d)
        except ReneusError as e:
            raise ReneusError(f'{where}: {e}') from None
        return RunSpec(scene, data, config, preset, None if bounds is None else tuple(map(tuple, bounds)),
                       fingerprint)

    def same_run(self, other: 'RunSpec') -> bool:
        """Whether two specs describe the same run (a fingerprint not yet taken matches any)."""
        a, b = self.to_dict(), other.to_dict()
        if a['data_fingerprint'] is None or b['data_fingerprint'] is None:
            a['data_fingerprint'] = b['data_fingerprint'] = None
        return a == b

    def with_data(self, data: str) -> 'RunSpec':
        """The run on the dataset in ``data``, which must be the one it was started on (moved)."""
        from reneus_mi.data import load_dataset
        from reneus_mi.data.dataset import check_same_dataset
        if self.data_fingerprint is not None:
            moved = load_dataset(data, need_container=False, max_size=self.config.train.max_image_size)
            check_same_dataset(self.data_fingerprint, moved, f'--data {data}: not the dataset this run was '
                               'started on')
        return dataclasses.replace(self, data=data)


def read_spec(out: str) -> RunSpec:
    """The spec recorded in a run folder's ``config.json``."""
    folder = RunFolder(out)
    return RunSpec.from_dict(folder.read_config(), folder.config)


def spec_of_scene(scene_path: str, data: str | None):
    """The run of a scene XML: its integrator's model, its preset's training, its dataset."""
    from reneus_mi.presets import preset
    from reneus_mi.render.loading import load_scene, reneus_integrator
    integrator = reneus_integrator(load_scene(scene_path), scene_path)
    data = data or integrator.dataset
    if not data:
        raise ReneusError(f'{scene_path}: no dataset: give the integrator '
                          '<string name="dataset" value="FOLDER"/> or pass --data')
    if not os.path.isabs(data):
        data = os.path.join(os.path.dirname(os.path.abspath(scene_path)), data)
    config = ReconstructionConfig(model=integrator.model, train=preset(integrator.preset).train)
    return RunSpec(scene_path, data, config, integrator.preset)


def make_trainer(spec: RunSpec, out: str, scene_path: str | None = None):
    """The scene, dataset and trainer of ``spec``; the integrator renders ``spec.config.model``.

    ``scene_path`` loads the scene from elsewhere than ``spec.scene`` (a run's own copy)."""
    from reneus_mi.data import load_dataset
    from reneus_mi.data.dataset import dataset_fingerprint
    from reneus_mi.render.loading import check_field_reaches, load_scene, reneus_integrator
    from reneus_mi.geometry.surface import check_resolution
    from reneus_mi.train.pixel_sampler import BYTES_PER_PIXEL
    from reneus_mi.train.trainer import BUDGET_RANGE, Trainer, check_batch
    scene_path = scene_path or spec.scene
    scene = load_scene(scene_path)
    integrator = reneus_integrator(scene, scene_path)
    integrator.configure(with_refinement(spec.config).model)
    train = spec.config.train
    check_batch(train.batch_rays * (BUDGET_RANGE if train.sample_budget else 1), spec.config.model,
                '--batch-rays' + (' (x8: the largest batch under --sample-budget)' if train.sample_budget else ''))
    check_resolution(train.mesh_resolution, '--mesh-resolution')
    dataset = load_dataset(spec.data, need_container=spec.config.model.render.mode != 'neus',
                           max_size=train.max_image_size, extra_per_pixel=BYTES_PER_PIXEL)
    if spec.data_fingerprint is None:
        spec.data_fingerprint = dataset_fingerprint(dataset)
    frame = integrator.frame_of(scene)
    if frame.bounds is not None:
        check_field_reaches(frame.center, frame.scale, *frame.bounds, scene_path)
    if spec.mesh_bounds is not None:
        frame = dataclasses.replace(frame, bounds=spec.mesh_bounds)
    return Trainer(scene, dataset, spec.config.train, out, frame=frame)


def with_refinement(config: ReconstructionConfig) -> ReconstructionConfig:
    """The configuration whose model has the parameters that its training refines: the
    container's pose, and the light model that ``train.refine.light`` names."""
    from reneus_mi.config import replace
    refine, render = config.train.refine, config.model.render
    changes = {}
    if refine.pose:
        changes['model.render.container_pose'] = True
    if refine.light != 'none':
        changes['model.render.light'] = refine.light
    if refine.any() and render.mode == 'neus':
        raise ReneusError('train.refine (ior, pose, light) needs a container: mode is neus')
    return replace(config, **changes)


def run(spec: RunSpec, out: str, *, resume: bool = False, progress: bool = True) -> dict:
    """Train ``spec`` in folder ``out`` (continuing its checkpoint with ``resume``); return the result."""
    from reneus_mi.render.loading import copy_scene
    from reneus_mi.train.trainer import TrainingError
    folder = RunFolder(out)
    folder.check_start(resume)
    folder.check(inputs=[spec.scene, spec.data], resume=resume)
    trainer = make_trainer(spec, out, folder.scene_to_load(spec.scene) if resume else spec.scene)
    os.makedirs(out, exist_ok=True)
    with folder.lock():
        folder.remove_stray_temporaries()
        if resume:
            check_npz_file(folder.checkpoint, 'checkpoint')
            trainer.resume()
        else:
            copy_scene(spec.scene, folder.scene_copy)
        folder.clear_result()
        folder.write_config(spec.to_dict())
        try:
            result = trainer.run(progress=progress)
        except TrainingError as e:
            result = {'failure': str(e), 'iterations': trainer.iteration}
        folder.write_result(result)
    return result


def run_many(specs: dict[str, RunSpec], root: str, *, progress: bool = False) -> dict[str, dict]:
    """Run each spec in ``root/<name>`` by its folder's state: a finished (or failed) run is
    read back, a killed one resumed, a new one started.

    A folder whose recorded spec differs from the one asked for is an error
    (choose another root), never silently overwritten.
    """
    results = {}
    for name, spec in specs.items():
        folder = RunFolder(os.path.join(root, name))
        if os.path.isfile(folder.config) and not read_spec(folder.path).same_run(spec):
            raise ReneusError(f'{folder.path}: holds a run with other settings; choose another folder')
        state = folder.state()
        if state.name in ('finished', 'failed'):
            results[name] = folder.read_result()
            continue
        results[name] = run(spec, folder.path, resume=state.name == 'resumable', progress=progress)
    return results
