"""`make_cubes`: printable ARcubes (a one-page net, or the faces as tiles on several
sheets; a PDF and 300 dpi PNGs per model) and the ChArUco board that `calibrate_camera` reads.

    make_cubes c0-4-1-2-3-6/u c0-1-2-4-5-3/m+y --out cubes/ --cube-size 0.05 --tag-size 0.04
    make_cubes --model-set robot --out cubes/ --cube-size 0.05 --tag-size 0.04
    make_cubes --charuco --out cubes/ [--paper letter]

A model name is c<tags on body faces +x -x +y -y +z -z>/<mass> (docs/MODEL.md; mass u, or
m+x ... m-z for a cube heavy towards that face). --model-set takes the model-set
parameters the nodes take (model_set, model_set_size, n_tags, seed, model_file).
The cube and tag sizes default to the tag detector's cube_size and marker_size, and the
dictionary to its dictionary: print at the sizes the detector is configured for, or set
the detector (and the aspect matcher's cube_size) to the sizes you print.
--layout: a one-piece net to fold (net), or the six faces as separate squares, as many per
sheet as fit, to glue on a solid cube or box of that size, each edge labelled with the
face it meets (tiles: one multi-page PDF, <name>_page<k>.png per page). The default (auto)
prints the net when it fits on the sheet, else tiles; --layout net refuses a net that does
not fit, naming the largest cube that does. The default 10 cm cube tiles on 3 A4 sheets.
Pages: see docs/PRINTED_CUBES.md.
"""

from __future__ import annotations

import argparse
import os
import sys

from abp_belief import model_file, population
from abp_perception.charuco_calibration import BoardSpec
from abp_perception.node_parameters import DETECTOR_SPECS

from . import cube_net, cube_tiles, printable_pages

_DETECTOR_DEFAULTS = {spec.name: spec.default for spec in DETECTOR_SPECS}
BOARD_PX_PER_MM = 2.0          # the default board's squares and modules are whole pixels
LAYOUTS = ('auto', 'net', 'tiles')


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='make_cubes', description='Printable ARcubes (PDF + 300 dpi PNGs per model): a '
        'net to fold, or the six faces as tiles for a solid cube or box (--layout); and the '
        'ChArUco calibration board.',
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument('models', nargs='*', metavar='MODEL',
                        help='model names, e.g. c0-4-1-2-3-6/u c0-1-2-4-5-3/m+y')
    parser.add_argument('--out', required=True, metavar='DIR', help='folder for the pages')
    parser.add_argument('--paper', choices=sorted(cube_net.PAPER_MM), default='a4')
    parser.add_argument('--cube-size', type=float, default=_DETECTOR_DEFAULTS['cube_size'],
                        metavar='M', help="cube edge, m (default: the detector's cube_size, "
                        f"{_DETECTOR_DEFAULTS['cube_size']:g})")
    parser.add_argument('--tag-size', type=float, default=_DETECTOR_DEFAULTS['marker_size'],
                        metavar='M', help="tag edge (black square), m (default: the "
                        f"detector's marker_size, {_DETECTOR_DEFAULTS['marker_size']:g})")
    parser.add_argument('--dictionary', default=_DETECTOR_DEFAULTS['dictionary'],
                        help="ArUco dictionary (default: the detector's, "
                        f"{_DETECTOR_DEFAULTS['dictionary']})")
    parser.add_argument('--model-set', choices=population.MODEL_SETS, default=None,
                        help='every model of this generated set (as the model_set parameter)')
    parser.add_argument('--model-set-size', type=int, default=30, metavar='N',
                        help='visual cubes of --model-set random (default 30)')
    parser.add_argument('--n-tags', type=int, default=7, metavar='N',
                        help='tag set size of --model-set (default 7)')
    parser.add_argument('--seed', type=int, default=0, help='seed of --model-set (default 0)')
    parser.add_argument('--model-file', default='', metavar='FILE',
                        help='every model of a model-set file (`models --out`, `learn_atg`)')
    parser.add_argument('--layout', choices=LAYOUTS, default='auto',
                        help='net: one-piece net to fold (refused if it does not fit the '
                        'sheet); tiles: the six faces as separate squares, as many per sheet '
                        'as fit, to glue on a solid cube or box, each edge labelled with the '
                        'face it meets; auto (default): the net if it fits, else tiles')
    parser.add_argument('--charuco', action='store_true',
                        help=f'also print the calibration board ({BoardSpec().describe()})')
    return parser


def _error(parser, message: str, status: int = 2) -> int:
    if status == 2:
        parser.print_usage(sys.stderr)
    print(f'{parser.prog}: error: {message}', file=sys.stderr)
    return status


def _models(args) -> list[tuple[str, tuple, int]]:
    """(name, faces, mass index) of every model asked for, named ones first, no repeats."""
    found = {}
    for name in args.models:
        faces, mass = cube_net.parse_model_name(name)
        found.setdefault(name, (faces, mass))
    if args.model_set or args.model_file:
        model_set = population.model_set_from_config(
            args.model_set or 'robot', args.model_set_size, args.n_tags, args.seed,
            model_file=args.model_file)
        for name, faces, mass in zip(model_set.names, model_set.faces, model_set.mass):
            found.setdefault(name, (tuple(int(t) for t in faces), int(mass)))
    return [(name, faces, mass) for name, (faces, mass) in found.items()]


def file_stem(name: str) -> str:
    """'c0-1-2-4-5-3/m+y' -> 'c0-1-2-4-5-3_m+y' (a model name has one slash)."""
    return name.replace('/', '_')


def board_page(spec: BoardSpec, paper: str):
    w, h = spec.size_mm
    notes = [
        f'{spec.describe()}: {w:g} x {h:g} mm as printed. Print at 100 % ("actual size") '
        'and check the bar.',
        'Glue it flat on card or board (a bent board makes a bad calibration). Then film or '
        'photograph it from 15-30 positions: near and far,',
        'tilted up to about 45 degrees, in every part of the image, and run '
        '`calibrate_camera PICTURES --out camera.yaml` (docs/PRINTED_CUBES.md).',
    ]
    return printable_pages.draw_board_page(spec.image(BOARD_PX_PER_MM), BOARD_PX_PER_MM,
                                           cube_net.PAPER_MM[paper],
                                           'ChArUco calibration board', notes)


def _layout(layout: str, name, faces, mass, **sizes):
    """A model's net (a CubePage) or its tile sheets (a list of TilePage)."""
    if layout == 'auto':
        try:
            return cube_net.cube_page(name, faces, mass, **sizes)
        except cube_net.NetDoesNotFit:
            layout = 'tiles'
    if layout == 'tiles':
        return cube_tiles.tile_pages(name, faces, mass, **sizes)
    return cube_net.cube_page(name, faces, mass, **sizes)


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:                     # --help (0) or a usage error (2)
        return int(exc.code or 0)
    if not (args.models or args.model_set or args.model_file or args.charuco):
        return _error(parser, 'name models, or give --model-set, --model-file or --charuco')
    if args.model_set and args.model_file:
        return _error(parser, '--model-set and --model-file are mutually exclusive')
    cube_mm, tag_mm = args.cube_size * 1000.0, args.tag_size * 1000.0
    try:
        models = _models(args)
        # Every page is laid out before any is written: a refusal leaves no files behind.
        pages = [_layout(args.layout, name, faces, mass, cube_mm=cube_mm, tag_mm=tag_mm,
                         paper=args.paper, dictionary=args.dictionary)
                 for name, faces, mass in models]
    except cube_net.NetDoesNotFit as exc:
        return _error(parser, str(exc), status=1)
    except (ValueError, model_file.ModelFileError) as exc:
        return _error(parser, str(exc))
    try:
        os.makedirs(args.out, exist_ok=True)
        for page in pages:
            if isinstance(page, list):                # a model's tile sheets
                pdf, pngs = printable_pages.save_pages(
                    [printable_pages.draw_tile_page(p) for p in page],
                    os.path.join(args.out, file_stem(page[0].name)))
                print(f'{page[0].name}: {pdf} {" ".join(pngs)} (faces on {len(pngs)} '
                      f'sheet{"s" if len(pngs) > 1 else ""}, to glue on a solid cube or box)')
                continue
            pdf, png = printable_pages.save_page(
                printable_pages.draw_cube_page(page), os.path.join(args.out, file_stem(page.name)))
            print(f'{page.name}: {pdf} {png}')
        if args.charuco:
            pdf, png = printable_pages.save_page(board_page(BoardSpec(), args.paper),
                                                 os.path.join(args.out, 'charuco_board'))
            print(f'ChArUco board: {pdf} {png}')
    except OSError as exc:
        return _error(parser, f'cannot write to {args.out}: {exc.strerror or exc}', status=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
