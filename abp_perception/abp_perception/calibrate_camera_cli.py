"""`ros2 run abp_perception calibrate_camera`: camera intrinsics from pictures of the
printed ChArUco board (`make_cubes --charuco`), written as a camera_calibration YAML.

    calibrate_camera PICTURES --out camera.yaml [--camera-name webcam] [--max-error 1.0]
                     [--min-views 10] [--every N] [--squares 5 7 --square-mm 30 --marker-mm 21]

PICTURES is a folder of images or a video file (every N-th frame with --every). Show the
whole board, flat, from 15-30 positions: near and far, tilted up to about 45 degrees, in
every part of the image. The RMS reprojection error and the views used are printed; no
file is written (exit 1) when fewer than --min-views pictures show the board or the error
is above --max-error pixels.
"""

from __future__ import annotations

import argparse
import sys

from . import camera_calibration_file
from .charuco_calibration import BoardSpec, CalibrationError, calibrate, iter_pictures


def build_parser() -> argparse.ArgumentParser:
    spec = BoardSpec()
    parser = argparse.ArgumentParser(
        prog='calibrate_camera', description='Camera intrinsics from pictures of a printed '
        'ChArUco board, written in the camera_calibration YAML format.',
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument('pictures', help='folder of images, or a video file')
    parser.add_argument('--out', required=True, metavar='FILE', help='calibration YAML to write')
    parser.add_argument('--camera-name', default='camera', help="camera_name in the file "
                        "(default 'camera')")
    parser.add_argument('--max-error', type=float, default=1.0, metavar='PX',
                        help='refuse above this RMS reprojection error (default 1.0 px)')
    parser.add_argument('--min-views', type=int, default=10, metavar='N',
                        help='refuse with fewer usable pictures (default 10)')
    parser.add_argument('--k-coefficients', type=int, choices=(2, 3), default=2,
                        help='radial distortion terms: 2 (k1 k2, k3 = 0; the default, as '
                        "ROS's camera_calibration) or 3")
    parser.add_argument('--every', type=int, default=1, metavar='N',
                        help='use every N-th picture or video frame (default 1)')
    parser.add_argument('--squares', type=int, nargs=2, default=(spec.squares_x, spec.squares_y),
                        metavar=('X', 'Y'), help=f'board squares across and down (default '
                        f'{spec.squares_x} {spec.squares_y})')
    parser.add_argument('--square-mm', type=float, default=spec.square_mm,
                        help=f'square edge as printed (default {spec.square_mm:g})')
    parser.add_argument('--marker-mm', type=float, default=spec.marker_mm,
                        help=f'marker edge as printed (default {spec.marker_mm:g})')
    parser.add_argument('--dictionary', default=spec.dictionary,
                        help=f'markers of the board (default {spec.dictionary})')
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:                     # --help (0) or a usage error (2)
        return int(exc.code or 0)
    if not args.max_error > 0 or args.min_views < 3:
        parser.print_usage(sys.stderr)
        print(f'{parser.prog}: error: --max-error must be > 0 and --min-views >= 3',
              file=sys.stderr)
        return 2
    try:
        spec = BoardSpec(args.squares[0], args.squares[1], args.square_mm, args.marker_mm,
                         args.dictionary)
        result = calibrate(iter_pictures(args.pictures, args.every), spec,
                           min_views=args.min_views, max_error_px=args.max_error,
                           radial_coefficients=args.k_coefficients)
    except (CalibrationError, ValueError) as exc:
        print(f'{parser.prog}: error: {exc}; nothing written', file=sys.stderr)
        return 1
    K, D = result.camera_matrix, result.distortion
    calibration = camera_calibration_file.make(K, D, result.image_size, args.camera_name)
    try:
        camera_calibration_file.save(args.out, calibration)
    except OSError as exc:
        print(f'{parser.prog}: error: cannot write {args.out}: {exc.strerror or exc}',
              file=sys.stderr)
        return 1
    total = len(result.views_used) + len(result.views_skipped)
    print(f'board: {spec.describe()}')
    print(f'views used: {len(result.views_used)} of {total}')
    for name, why in result.views_skipped:
        print(f'  skipped {name}: {why}')
    print(f'RMS reprojection error: {result.rms_px:.3f} px (limit {args.max_error:g})')
    print(f'image {result.image_size[0]} x {result.image_size[1]}: fx {K[0, 0]:.2f} '
          f'fy {K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f}; '
          f'distortion {" ".join(f"{v:.4g}" for v in D)}')
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
