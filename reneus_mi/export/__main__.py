"""``python -m reneus_mi.export RUN -o PACKAGE``: a finished run (or every finished specimen of a
batch folder) as a specimen's package: the mesh, metadata.json, record.csv and the report
page (:mod:`~reneus_mi.export.package`, :mod:`~reneus_mi.export.page`)."""
from __future__ import annotations

import argparse
import os
import shutil
import sys

from reneus_mi.batch.packages import export_batch
from reneus_mi.export.package import IDENTIFIERS, export_run
from reneus_mi.train.run_folder import RunFolder
from reneus_mi.utils import guards
from reneus_mi.utils.errors import exit_on_error


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m reneus_mi.export', description=__doc__.split('\n\n')[0])
    parser.add_argument('run', metavar='RUN', help='a finished run folder, or a batch folder (every finished '
                        'specimen)')
    parser.add_argument('-o', '--output', required=True, metavar='PACKAGE', help='the package folder to write '
                        '(new or empty); for a batch folder, one package per specimen inside it')
    parser.add_argument('--zip', action='store_true', help='also write PACKAGE.zip')
    parser.add_argument('--watertight', action='store_true', help='add a variant of the mesh with its holes '
                        'closed (metadata.json says how many)')
    parser.add_argument('--creator', help="who made the model (Audubon Core's dc:creator)")
    for term in IDENTIFIERS:
        parser.add_argument('--' + term, dest=term, metavar='TEXT', help=f"Darwin Core's {term} (for a batch: "
                            'over the manifest column of that name)')
    args = parser.parse_args(argv)
    identifiers = {term: getattr(args, term) for term in IDENTIFIERS}
    with exit_on_error(RuntimeError):
        # The archive is checked first: no file the command did not make is ever replaced.
        archive = (guards.check_output_file(os.path.abspath(args.output) + '.zip', inputs=[args.run],
                                            what='package archive', overwrite_flag=None) if args.zip else None)
        if os.path.isfile(RunFolder(args.run).result) or not os.path.isdir(args.run):
            export_run(args.run, args.output, identifiers=identifiers, creator=args.creator,
                       watertight=args.watertight)
            packages = [args.output]
        else:
            packages, left_out = export_batch(args.run, args.output, identifiers=identifiers,
                                              creator=args.creator, watertight=args.watertight)
            for specimen, state in left_out.items():
                print(f'warning: {specimen}: left out: its run is {state}', file=sys.stderr)
        if archive:
            packages.append(shutil.make_archive(archive[:-len('.zip')], 'zip', args.output))
    print(f"wrote {', '.join(packages) or 'nothing (no finished specimen)'}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
