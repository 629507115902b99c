"""A collection of specimens reconstructed as one job, on a laptop, a workstation or a cluster.

``python -m reneus_mi.batch COLLECTION -o RUNS_DIR`` (:mod:`~reneus_mi.batch.__main__`):

- :mod:`~reneus_mi.batch.collection`: the specimens of a folder or a manifest (CSV, JSON);
- :mod:`~reneus_mi.batch.batch_folder`: where the batch keeps what (RUNS_DIR's layout);
- :mod:`~reneus_mi.batch.worker`: one specimen's run (:func:`reneus_mi.runs.prepare`),
  the same function on every engine;
- :mod:`~reneus_mi.batch.engines`: where the runs run: a local pool, Ray, Slurm (submitit);
- :mod:`~reneus_mi.batch.dispatch`: the batch: each run by its state, failures recorded, the
  summary rewritten as runs end;
- :mod:`~reneus_mi.batch.summary`: ``summary.csv``, ``summary.html``, the progress line.
"""
