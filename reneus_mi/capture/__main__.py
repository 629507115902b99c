"""``python -m reneus_mi.capture PHOTOS -o DATASET``: from a folder of photographs to a dataset
(the pipeline: :mod:`~reneus_mi.capture.pipeline`)."""
from __future__ import annotations

import argparse
import os
import sys
import warnings

import cv2

from reneus_mi.capture import photos, settings as settings_mod, writer
from reneus_mi.capture.pipeline import run
from reneus_mi.utils import cli, guards, interrupt
from reneus_mi.utils.errors import exit_on_error


def _left(out: str) -> str:
    """What an interrupted capture leaves in ``out``."""
    if guards.is_dataset_dir(out):
        return f'{out} holds the whole dataset (its transforms.json is written last)'
    if os.path.isdir(out):
        return f'{out} holds no dataset yet (no transforms.json): the same command replaces what it holds'
    return 'nothing was written'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m reneus_mi.capture',
        description='From photographs of a container standing on a printed ChArUco board to a '
                    'reneus-mi dataset: calibration, undistortion, the container found, exposure '
                    'and light measured. Coordinates: the board\'s frame (OpenCV ChArUco: origin at '
                    'the board\'s outer corner, x along the columns, y along the rows, z into the '
                    'table), millimetres.')
    parser.add_argument('photos', metavar='PHOTOS_DIR', help='folder of photographs (JPEG, PNG, TIFF)')
    parser.add_argument('-o', '--output', required=True, metavar='DATASET_DIR', help='dataset folder to write (new or empty)')
    parser.add_argument('--settings', metavar='FILE', help=f'capture settings file (default: PHOTOS_DIR/{settings_mod.CAPTURE_FILE} if present)')
    parser.add_argument('--quiet', action='store_true', help='print no table')
    parser.add_argument('--crop-to-coverage', action='store_true',
                        help="crop the dataset's images to the part of the frame the board covered, where the "
                             'lens model is measured, not extrapolated (report.json: camera.coverage)')
    cli.add_arguments(parser, settings_mod.CaptureSettings, as_text=True,
                      title=f'capture settings (or in {settings_mod.CAPTURE_FILE} beside the photographs)')
    args = parser.parse_args(argv)
    interrupt.leaving(lambda: _left(args.output))
    with exit_on_error(RuntimeError, cv2.error):
        with warnings.catch_warnings():
            # Every photograph's warning, even where two come from one line of code.
            warnings.simplefilter('always')
            photos.check_folder(args.photos)
            settings = settings_mod.resolve(args, args.photos, args.settings)
            report = run(settings, args.photos, args.output, crop=args.crop_to_coverage)
    if not args.quiet:
        print(writer.table(report))
    print(f"wrote {args.output}: {len(report['views'])} views, container at x={report['container']['pose'][0]:.2f} mm, "
          f"y={report['container']['pose'][1]:.2f} mm, yaw={report['container']['pose'][2]:.2f} deg "
          f"(residual {report['container']['residual_px']:.2f} px), {report['seconds']:.0f} s")
    return 0


if __name__ == '__main__':
    sys.exit(main())
