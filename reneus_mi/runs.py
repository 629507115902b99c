"""Runs: one reconstruction in one folder, and many of them.

:func:`prepare` makes a :class:`Run` from a scene (or, to continue, from a run folder): it
checks the folder, loads the scene and the dataset once, resolves the configuration once
(the integrator's model, its preset's training, the settings given) and builds the trainer
on them; :meth:`Run.train` trains it in its folder
(:class:`~reneus_mi.train.run_folder.RunFolder`) and writes ``config.json`` (the
:class:`RunSpec`, the run's record, from which :func:`read_spec` and :func:`run_many`
rebuild it) and ``result.json``. :func:`run_many` goes through a collection by the state of
each folder, skipping finished runs and resuming killed ones, so that a batch of specimens
(or a benchmark table) can be interrupted and started again at no cost.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from typing import Callable, Sequence

import mitsuba as mi

from reneus_mi.config import ReconstructionConfig, from_dict, replace, to_dict, with_settings
from reneus_mi.data import Dataset, load_dataset
from reneus_mi.data.dataset import check_same_dataset, dataset_fingerprint
from reneus_mi.geometry.surface import check_resolution
from reneus_mi.presets import preset
from reneus_mi.render.loading import check_field_reaches, load_scene, reneus_integrator
from reneus_mi.train.pixel_sampler import BYTES_PER_PIXEL
from reneus_mi.train.run_folder import RunFolder
from reneus_mi.train.trainer import BUDGET_RANGE, Trainer, TrainingError, check_batch
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import check_npz_file


@dataclass
class RunSpec:
    """A run's record (``config.json``): enough to build it again."""
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
        preset_name, bounds, fingerprint = d.pop('preset', ''), d.pop('mesh_bounds', None), d.pop('data_fingerprint', None)
        try:
            config = from_dict(ReconstructionConfig, d)
        except ReneusError as e:
            raise ReneusError(f'{where}: {e}') from None
        return RunSpec(scene, data, config, preset_name, None if bounds is None else tuple(map(tuple, bounds)),
                       fingerprint)

    def same_run(self, other: 'RunSpec') -> bool:
        """Whether two specs describe the same run (a fingerprint not yet taken matches any)."""
        a, b = self.to_dict(), other.to_dict()
        if a['data_fingerprint'] is None or b['data_fingerprint'] is None:
            a['data_fingerprint'] = b['data_fingerprint'] = None
        return a == b


@dataclass
class Run:
    """A run ready to train: its record, its folder, the scene and dataset it was built on, and
    whether it continues the folder's checkpoint."""
    spec: RunSpec
    folder: RunFolder
    scene: mi.Scene
    dataset: Dataset
    resume: bool

    def trainer(self) -> Trainer:
        """The trainer of the run (from its checkpoint when it continues one)."""
        frame = reneus_integrator(self.scene, self.spec.scene).frame_of(self.scene)
        if self.spec.mesh_bounds is not None:
            frame = dataclasses.replace(frame, bounds=self.spec.mesh_bounds)
        return Trainer(self.scene, self.dataset, self.spec.config.train, self.folder, frame=frame,
                       resume=self.resume)

    def train(self, progress: bool = True) -> dict:
        """Train in the run's folder, under its lock; return the result (also ``result.json``)."""
        folder = self.folder
        os.makedirs(folder.path, exist_ok=True)
        with folder.lock():
            folder.remove_stray_temporaries()
            if self.resume:
                check_npz_file(folder.checkpoint, 'checkpoint')
            trainer = self.trainer()
            if not self.resume:
                folder.keep_scene(self.spec.scene)
            folder.clear_result()
            folder.write_config(self.spec.to_dict())
            try:
                result = trainer.run(progress=progress)
            except TrainingError as e:
                result = {'failure': str(e), 'iterations': trainer.iteration}
            folder.write_result(result)
        return result


#: How :func:`prepare` takes its folder: ``new``, a run that starts there (the folder must take
#: one); ``resume``, the run the folder records (its config.json), from its checkpoint;
#: ``continue``, the folder as it is (a batch's specimen): the run of the scene given, from the
#: folder's checkpoint where it has one.
STARTS = ('new', 'resume', 'continue')


def prepare(out: str, scene: str | Callable[[], str] | None = None, data: str | None = None, *,
            train: dict | None = None, settings: Sequence[str] = (), start: str = 'new',
            remedy: str = 'choose another folder') -> Run:
    """The run in folder ``out``, started as ``start`` says (:data:`STARTS`): of ``scene``
    (with its integrator's ``dataset``, or ``data``), or the one the folder records (``data``:
    its dataset, moved). ``train`` sets training fields by name and ``settings`` any setting
    (``PATH=VALUE``), in that order, over the integrator's model and its preset's training (or
    the record's). ``scene`` may be a function that writes the scene (the demo), called once
    the folder is known to take the run. A folder that records a run of other settings than
    ``continue``'s is an error (its message ends with ``remedy``)."""
    if start not in STARTS:
        raise ValueError(f'start={start!r}: expected one of {STARTS}')
    folder = RunFolder(out)
    resume = start == 'resume' or (start == 'continue' and os.path.isfile(folder.checkpoint))
    folder.check_start(resume)
    if start == 'resume':
        spec = read_spec(out)
        if scene is not None:
            raise ReneusError(f'{out}: --resume continues the run recorded in its config.json '
                              f'(scene {spec.scene}), but {scene} was given; expected no scene')
        spec.config = _with(spec.config, train, settings)
        return _open(spec, folder, resume=True, moved=data)
    folder.check(inputs=[s for s in (scene, data) if isinstance(s, str)], resume=resume)
    if callable(scene):
        scene = scene()
    loaded = load_scene(scene)
    spec = _spec(scene, loaded, data, train, settings)
    if start == 'continue' and os.path.isfile(folder.config):
        recorded = read_spec(out)
        if not recorded.same_run(spec):
            raise ReneusError(f'{out}: holds a run with other settings; expected the same settings, '
                              f'or {remedy}')
        spec = recorded if resume else spec
    return _build(spec, folder, loaded, resume=resume)


def spec_of_scene(scene: str, data: str | None = None, *, train: dict | None = None,
                  settings: Sequence[str] = ()) -> RunSpec:
    """The record of a run of ``scene`` (as :func:`prepare` makes it), for a collection
    (:func:`run_many`)."""
    return _spec(scene, load_scene(scene), data, train, settings)


def _spec(path: str, scene: mi.Scene, data: str | None, train: dict | None, settings: Sequence[str]) -> RunSpec:
    """The run of the loaded scene ``path``: its integrator's model, its preset's training, the
    ``train`` fields and ``settings`` over them; its dataset ``data`` or the integrator's."""
    integrator = reneus_integrator(scene, path)
    data = data or integrator.dataset
    if not data:
        raise ReneusError(f'{path}: no dataset: give the integrator '
                          '<string name="dataset" value="FOLDER"/> or pass --data')
    if not os.path.isabs(data):
        data = os.path.join(os.path.dirname(os.path.abspath(path)), data)
    config = ReconstructionConfig(model=integrator.model, train=preset(integrator.preset).train)
    return RunSpec(path, data, _with(config, train, settings), integrator.preset)


def _with(config: ReconstructionConfig, train: dict | None, settings: Sequence[str]) -> ReconstructionConfig:
    """``config`` with the ``train`` fields by name, then the ``settings`` (``PATH=VALUE``)."""
    config = replace(config, **{f'train.{k}': v for k, v in (train or {}).items()})
    return with_settings(config, settings)[0]


def _open(spec: RunSpec, folder: RunFolder, *, resume: bool, moved: str | None = None) -> Run:
    """The run of a record in ``folder``, checked (``moved``: its dataset, given anew)."""
    if moved:
        spec = dataclasses.replace(spec, data=os.path.abspath(moved))
    folder.check(inputs=[spec.scene, spec.data], resume=resume)
    scene = load_scene(folder.scene_to_load(spec.scene) if resume else spec.scene)
    return _build(spec, folder, scene, resume=resume, moved=moved)


def _build(spec: RunSpec, folder: RunFolder, scene: mi.Scene, *, resume: bool, moved: str | None = None) -> Run:
    """The run of ``spec`` on the loaded ``scene``: its integrator set to the spec's model, the
    configuration checked, the dataset loaded (``moved``: checked to be the run's own)."""
    integrator = reneus_integrator(scene, spec.scene)
    integrator.configure(spec.config.model, refine=spec.config.train.refine)
    train = spec.config.train
    check_batch(train.batch_rays * (BUDGET_RANGE if train.sample_budget else 1), spec.config.model,
                '--batch-rays' + (' (x8: the largest batch under --sample-budget)' if train.sample_budget else ''))
    check_resolution(train.mesh_resolution, '--mesh-resolution')
    dataset = load_dataset(spec.data, need_container=spec.config.model.render.mode != 'neus',
                           max_size=train.max_image_size, extra_per_pixel=BYTES_PER_PIXEL)
    if spec.data_fingerprint is None:
        spec.data_fingerprint = dataset_fingerprint(dataset)
    elif moved:
        check_same_dataset(spec.data_fingerprint, dataset, f'--data {spec.data}: not the dataset this run was '
                           'started on')
    frame = integrator.frame_of(scene)
    if frame.bounds is not None:
        check_field_reaches(frame.center, frame.scale, *frame.bounds, spec.scene)
    return Run(spec, folder, scene, dataset, resume)


def read_spec(out: str) -> RunSpec:
    """The spec recorded in a run folder's ``config.json``."""
    folder = RunFolder(out)
    return RunSpec.from_dict(folder.read_config(), folder.config)


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
        resume = state.name == 'resumable'
        folder.check_start(resume)
        results[name] = _open(spec, folder, resume=resume).train(progress)
    return results
