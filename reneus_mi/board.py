"""Write a ChArUco board to print: ``python -m reneus_mi.board -o board.png``.

The board (:mod:`reneus_mi.capture.charuco`) the capture finds in every photograph; print it
at 100 % and measure a square (docs/capture.md).
"""
from __future__ import annotations

import argparse
import sys

from reneus_mi.capture.charuco import Board, write_print
from reneus_mi.capture.settings import CaptureSettings, numbers
from reneus_mi.utils import guards
from reneus_mi.utils.errors import exit_on_error


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m reneus_mi.board',
                                     description='Write a ChArUco board to print at 100 % (docs/capture.md).')
    parser.add_argument('-o', '--output', required=True, help='PNG file to write')
    parser.add_argument('--squares', default='12x9', help='squares along the columns and rows (default: 12x9)')
    parser.add_argument('--square-mm', type=float, default=20.0, help='side of a square in mm (default: 20)')
    parser.add_argument('--marker-mm', type=float, default=15.0, help='side of a marker in mm (default: 15)')
    parser.add_argument('--dictionary', default='DICT_4X4_100', help='ArUco dictionary (default: DICT_4X4_100)')
    parser.add_argument('--dpi', type=float, default=600.0, help='printer resolution (default: 600)')
    args = parser.parse_args(argv)
    with exit_on_error():
        squares = numbers(args.squares, 2, int, 'x', 'squares', '--squares')
        CaptureSettings(squares=squares, square_mm=args.square_mm, marker_mm=args.marker_mm,
                        size_mm=(1.0, 1.0, 1.0), ior=1.5).check('board')
        board = Board(*squares, args.square_mm, args.marker_mm, args.dictionary)
        board.check()
        guards.check_output_file(args.output, extensions=('.png',))
        w, h = write_print(board, args.output, args.dpi)
    print(f'wrote {args.output}: {w}x{h} pixels at {args.dpi:g} dpi = {w / args.dpi * 25.4:.1f} x '
          f'{h / args.dpi * 25.4:.1f} mm; print at 100 % and measure a square')
    return 0


if __name__ == '__main__':
    sys.exit(main())
