"""A batch's finished specimens as packages for the collection (``python -m reneus_mi.export
BATCH -o PACKAGES``): each with the identifiers its manifest row gave."""
from __future__ import annotations

import os

from reneus_mi.batch.batch_folder import BatchFolder
from reneus_mi.export.package import check_identifiers, export_run, package_name
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import read_json


def export_batch(runs_dir: str, out: str, **options) -> tuple[list[str], dict[str, str]]:
    """Every finished specimen of a batch folder into ``out/NAME``, with the identifiers its
    manifest row gave; returns the packages written and the specimens left out, with why."""
    batch = BatchFolder(runs_dir)
    specimens = read_json(batch.collection)
    if specimens is None:
        raise ReneusError(f'{runs_dir}: not a run folder (no result.json) nor a batch folder (no '
                          f'{os.path.relpath(batch.collection, runs_dir)}); expected one of them')
    given = check_identifiers(options.pop('identifiers', {}))
    # Which specimens go, each checked, before anything is written.
    chosen, left_out = [], {}
    for s in specimens:
        state = batch.run(s['name']).state()
        if state.name != 'finished':
            left_out[s['name']] = str(state)
            continue
        identifiers = {**check_identifiers(s.get('identifiers', {}), f"{s['name']}: "), **given}
        chosen.append((s['name'], identifiers, package_name(identifiers.get('catalogNumber') or s['name'])))
    if len(chosen) > 1 and given.get('catalogNumber'):
        raise ReneusError(f"--catalogNumber {given['catalogNumber']!r} for {len(chosen)} specimens "
                          f"({', '.join(n for n, _, _ in chosen)}); expected one catalogue number each: give "
                          "them in the manifest's catalogNumber column")
    names = [name for _, _, name in chosen]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ReneusError(f"{', '.join(twice)}: the package name of more than one specimen; expected a "
                          'catalogue number (or a name) each')
    out = guards.check_output_dir(out, inputs=[runs_dir], what='packages folder')
    written = []
    for specimen, identifiers, name in chosen:
        export_run(batch.run(specimen).path, os.path.join(out, name), identifiers=identifiers, **options)
        written.append(os.path.join(out, name))
    return written, left_out
