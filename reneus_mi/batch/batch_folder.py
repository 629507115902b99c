"""The batch folder: the one place that knows where a batch keeps what.

::

    RUNS_DIR/
        <name>/                 a specimen's run folder (reneus_mi.train.run_folder)
        summary.csv             one row per specimen, rewritten as runs end
        summary.html            the same with previews and links to the meshes
        _batch/
            .lock               the batch process driving the folder (one at a time)
            collection.json     the specimens of the last batch, as read
            slurm/              submitit's job files and logs (--engine slurm)
            <name>/             what the batch made for a specimen, beside its run:
                scene.xml           the scene its run was started from
                dataset/            the dataset captured from its photographs (a capture)
                preview.png         a render of its mesh
                metrics.json        Chamfer to the ground truth, where there is one
                package/            its package for the collection, with its report page
                                    (reneus_mi.export.package), once its run finished
                attempts.jsonl      one line per attempt: when, how long, how it ended
                worker.log          the local worker's output

Only the worker that holds a specimen's run lock writes into ``_batch/<name>``
(the batch process writes there too when a worker died, under the same lock).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass

from reneus_mi.train.run_folder import FolderFile, RunFolder, RunLock
from reneus_mi.utils.io import read_json

#: The batch's own folder inside RUNS_DIR (no specimen name starts with an underscore).
WORK = '_batch'
#: The summaries.
SUMMARY_CSV, SUMMARY_HTML = 'summary.csv', 'summary.html'
#: Names in RUNS_DIR that are not run folders.
RESERVED = (WORK, SUMMARY_CSV, SUMMARY_HTML)


@dataclass(frozen=True)
class SpecimenFiles:
    """What the batch keeps for one specimen beside its run folder."""
    path: str

    scene = FolderFile('scene.xml')
    dataset = FolderFile('dataset')
    preview = FolderFile('preview.png')
    metrics = FolderFile('metrics.json')
    package = FolderFile('package')
    attempts = FolderFile('attempts.jsonl')
    worker_log = FolderFile('worker.log')

    def page(self) -> str | None:
        """The report page of its package, None while it has none."""
        if not os.path.isdir(self.package):
            return None
        pages = [n for n in os.listdir(self.package) if n.endswith('.html')]
        return os.path.join(self.package, pages[0]) if pages else None

    def read_metrics(self) -> dict:
        return read_json(self.metrics) or {}

    def add_attempt(self, record: dict) -> None:
        """Append one attempt (a line: whole lines survive a kill, a torn last one is skipped)."""
        os.makedirs(self.path, exist_ok=True)
        with open(self.attempts, 'a') as f:
            f.write(json.dumps(record) + '\n')

    def read_attempts(self) -> list[dict]:
        if not os.path.isfile(self.attempts):
            return []
        out = []
        with open(self.attempts) as f:
            for line in f:
                try:
                    out.append(json.loads(line))
                except ValueError:
                    continue
        return out


@dataclass(frozen=True)
class BatchFolder:
    """RUNS_DIR: the run folders of a collection and what the batch keeps about them."""
    path: str

    def __post_init__(self):
        object.__setattr__(self, 'path', os.path.abspath(os.fspath(self.path)))

    work = FolderFile(WORK)
    summary_csv = FolderFile(SUMMARY_CSV)
    summary_html = FolderFile(SUMMARY_HTML)
    collection = FolderFile(WORK, 'collection.json')
    slurm = FolderFile(WORK, 'slurm')

    def lock(self) -> RunLock:
        """The batch's lock: one batch process drives a batch folder."""
        return RunLock(os.path.join(self.work, '.lock'), what='batch')

    def run(self, name: str) -> RunFolder:
        return RunFolder(os.path.join(self.path, name))

    def specimen(self, name: str) -> SpecimenFiles:
        return SpecimenFiles(os.path.join(self.work, name))


