"""Drawing the printable pages (matplotlib): an ARcube net (`cube_net.CubePage`) or the
ChArUco calibration board, each saved as a one-page PDF and a 300 dpi PNG of the sheet,
or a cube's faces as separate tiles (`cube_tiles.TilePage`), saved as one multi-page PDF
and a PNG per page.

The figure is the sheet itself (no tight bounding box, no axes margins), with data
coordinates in millimetres, so 1 mm on paper is 1 mm in the PDF and 300/25.4 pixels in
the PNG. Tags are vector paths (one compound path per image, no seams between modules),
sharp at any printer resolution.
"""

from __future__ import annotations

import os

import matplotlib

matplotlib.use('Agg')  # files only; never a window

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.backends.backend_pdf import PdfPages  # noqa: E402
from matplotlib.patches import PathPatch, Polygon, Rectangle  # noqa: E402
from matplotlib.path import Path  # noqa: E402

from .cube_net import MARGIN_MM, SCALE_BAR_MM, CubePage, CubeSheet  # noqa: E402
from .cube_tiles import TilePage, edge_label, face_label  # noqa: E402

PNG_DPI = 300
MM_PER_INCH = 25.4
PT_MM = 25.4 / 72   # one typographic point, mm
FOLD_STYLE = dict(color='0.35', linewidth=0.5, linestyle=(0, (4, 2)))
CUT_STYLE = dict(color='black', linewidth=0.6)


def _sheet(size_mm):
    w, h = size_mm
    fig = plt.figure(figsize=(w / MM_PER_INCH, h / MM_PER_INCH))
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(0.0, w)
    ax.set_ylim(0.0, h)
    ax.set_aspect('equal')
    ax.axis('off')
    return fig, ax


def binary_image_path(black: np.ndarray, origin, module_mm: float) -> Path | None:
    """One compound path of the black pixels of `black` (row 0 at the top), each pixel a
    square of `module_mm`, the image's bottom-left corner at `origin`; runs of black pixels
    in a row merge into one rectangle."""
    black = np.asarray(black, dtype=bool)
    rows = black.shape[0]
    verts, codes = [], []
    x0, y0 = origin
    for r in range(rows):
        line = np.concatenate([[False], black[r], [False]]).astype(np.int8)
        starts = np.flatnonzero(np.diff(line) == 1)
        ends = np.flatnonzero(np.diff(line) == -1)
        top = y0 + (rows - r) * module_mm
        bottom = top - module_mm
        for a, b in zip(starts, ends):
            left, right = x0 + a * module_mm, x0 + b * module_mm
            verts += [(left, bottom), (right, bottom), (right, top), (left, top), (left, bottom)]
            codes += [Path.MOVETO, Path.LINETO, Path.LINETO, Path.LINETO, Path.CLOSEPOLY]
    return Path(verts, codes) if verts else None


def _draw_black(ax, black, origin, module_mm):
    path = binary_image_path(black, origin, module_mm)
    if path is not None:
        ax.add_patch(PathPatch(path, facecolor='black', edgecolor='none', linewidth=0))


def draw_scale_bar(ax, x0: float, y0: float):
    """A SCALE_BAR_MM bar from (x0, y0) to the right, 1.5 mm high, ticks every cm."""
    ax.add_patch(Rectangle((x0, y0), SCALE_BAR_MM, 1.5, facecolor='black', edgecolor='none'))
    last = int(SCALE_BAR_MM // 10)
    for k in range(last + 1):
        x = x0 + 10.0 * k
        tall = k % 5 == 0
        # The end ticks stay inside the bar's length, so the bar measures exactly that.
        left = x if k == 0 else (x - 0.3 if k == last else x - 0.15)
        ax.add_patch(Rectangle((left, y0), 0.3, 4.0 if tall else 2.8, facecolor='black',
                               edgecolor='none'))
        if tall:
            ax.text(x, y0 + 4.8, f'{k} cm', ha='center', va='bottom', fontsize=7)
    ax.text(x0 + SCALE_BAR_MM + 4.0, y0 + 0.75,
            f'this bar must measure {SCALE_BAR_MM / 10:g} cm; if not, print at 100 %',
            ha='left', va='center', fontsize=7)


def _segments(ax, segments, style):
    for (xa, ya), (xb, yb) in segments:
        ax.plot([xa, xb], [ya, yb], solid_capstyle='butt', **style)


def draw_cube_page(page: CubePage):
    """The matplotlib figure of one cube's sheet (caller saves and closes it)."""
    fig, ax = _sheet(page.size_mm)
    for poly, label, centre, angle in page.tabs:
        ax.add_patch(Polygon(poly, closed=True, facecolor='0.92', edgecolor='none'))
        ax.text(*centre, label, ha='center', va='center', rotation=angle, fontsize=5.5,
                color='0.3')
    _segments(ax, page.folds, FOLD_STYLE)
    _segments(ax, page.cuts, CUT_STYLE)
    margin = (page.cube_mm - page.tag_mm) / 2
    for sq in page.squares:
        x, y = sq.origin
        module = page.tag_mm / sq.modules.shape[0]
        _draw_black(ax, sq.modules, (x + margin, y + margin), module)
        # The tag id in the border's corner, small and grey: people read it, detectors ignore it.
        ax.text(x + margin / 2, y + margin / 2, str(sq.tag_id), ha='center', va='center',
                fontsize=min(6.0, 0.45 * margin / PT_MM), color='0.45')
    _finish_sheet(ax, page, margin, f'ARcube {page.name}')
    return fig


def _finish_sheet(ax, page: CubeSheet, margin: float, title: str):
    """What every sheet of a cube has besides its squares: the weight mark (on an
    eccentric cube's heavy face), the title, the scale bar and the notes under it."""
    if page.weight_mark is not None:
        _weight_mark(ax, page.weight_mark, margin)
    _title(ax, page, title)
    bar_x, bar_y = page.scale_bar
    draw_scale_bar(ax, bar_x, bar_y)
    ax.text(MARGIN_MM, bar_y - 3.0, '\n'.join(page.notes), ha='left', va='top', fontsize=6.5,
            linespacing=1.35)


def _title(ax, page, title: str):
    w, h = page.size_mm
    top = h - MARGIN_MM
    ax.text(MARGIN_MM, top, title, ha='left', va='top', fontsize=14, fontweight='bold')
    ax.text(w - MARGIN_MM, top, f'cube {page.cube_mm:g} mm, tag {page.tag_mm:g} mm\n'
            f'{page.dictionary}, {page.paper.upper()}', ha='right', va='top', fontsize=8,
            linespacing=1.3)


def _weight_mark(ax, centre, margin):
    r = min(0.35 * margin, 3.0)
    ax.add_patch(plt.Circle(centre, r, facecolor='0.5', edgecolor='none'))
    ax.text(*centre, 'W', ha='center', va='center', fontsize=1.1 * r / PT_MM, color='white',
            fontweight='bold')


# Where each side's label sits (fraction of the border from the edge) and how it is turned.
_EDGE_TEXT = {'up': ((0.5, 1.0), (0.0, -1.0), 0.0), 'down': ((0.5, 0.0), (0.0, 1.0), 0.0),
              'left': ((0.0, 0.5), (1.0, 0.0), 90.0), 'right': ((1.0, 0.5), (-1.0, 0.0), -90.0)}


def draw_tile_page(page: TilePage):
    """The matplotlib figure of one sheet of tiles (caller saves and closes it): each face
    square outlined (cut line) with its tag, its face label in the border's bottom-left
    corner and, in the middle of each side's border, the face it meets there."""
    fig, ax = _sheet(page.size_mm)
    e = page.cube_mm
    margin = (e - page.tag_mm) / 2
    size = min(6.0, 0.45 * margin / PT_MM)
    for tile in page.tiles:
        x, y = tile.origin
        ax.add_patch(Rectangle((x, y), e, e, facecolor='none', edgecolor='black',
                               linewidth=0.6))
        module = page.tag_mm / tile.modules.shape[0]
        _draw_black(ax, tile.modules, (x + margin, y + margin), module)
        # Labels in the border's outer part, small and grey: people read them, the
        # detector ignores them (they stay clear of the tag's quiet zone).
        ax.text(x + 0.3 * margin, y + 0.4 * margin, face_label(tile.face, tile.tag_id),
                ha='left', va='center', fontsize=size, color='0.3', fontweight='bold')
        for side, other in tile.meets.items():
            (fx, fy), (ix, iy), angle = _EDGE_TEXT[side]
            ax.text(x + fx * e + ix * 0.4 * margin, y + fy * e + iy * 0.4 * margin,
                    edge_label(other, page.faces[other]), ha='center', va='center',
                    rotation=angle, fontsize=size, color='0.45')
    _finish_sheet(ax, page, margin,
                  f'ARcube {page.name}, faces page {page.number}/{page.page_count}')
    return fig


def save_pages(figs, stem: str) -> tuple[str, list[str]]:
    """Save `figs` as one multi-page `stem`.pdf and `stem`_page<k>.png (PNG_DPI), closing
    each; returns the paths."""
    pdf, pngs = stem + '.pdf', []
    tmp = pdf + '.part'
    try:
        with PdfPages(tmp, metadata={'Creator': 'abp make_cubes'}) as document:
            for k, fig in enumerate(figs, start=1):
                document.savefig(fig)
                png = f'{stem}_page{k}.png'
                fig.savefig(png + '.part', format='png', dpi=PNG_DPI,
                            pil_kwargs={'compress_level': 1})
                os.replace(png + '.part', png)
                pngs.append(png)
    finally:
        for fig in figs:
            plt.close(fig)
    os.replace(tmp, pdf)
    return pdf, pngs


def save_page(fig, stem: str) -> tuple[str, str]:
    """Save `fig` as `stem`.pdf and `stem`.png (PNG_DPI) and close it; returns the paths."""
    pdf, png = stem + '.pdf', stem + '.png'
    for path in (pdf, png):
        tmp = path + '.part'
        if path.endswith('.pdf'):
            fig.savefig(tmp, format='pdf', metadata={'Creator': 'abp make_cubes'})
        else:   # light compression: a third faster, files a half larger (~0.35 MB)
            fig.savefig(tmp, format='png', dpi=PNG_DPI, pil_kwargs={'compress_level': 1})
        os.replace(tmp, path)                     # never a half-written page under its name
    plt.close(fig)
    return pdf, png


def draw_board_page(board_image: np.ndarray, px_per_mm: float, size_mm, title: str,
                    notes: list[str]):
    """The ChArUco board (`board_image`, white = 255, at `px_per_mm`) centred on a sheet,
    with a scale bar and `notes`."""
    fig, ax = _sheet(size_mm)
    w, h = size_mm
    bh, bw = board_image.shape[0] / px_per_mm, board_image.shape[1] / px_per_mm
    x0 = (w - bw) / 2
    y0 = MARGIN_MM + 30.0 + (h - 2 * MARGIN_MM - 42.0 - bh) / 2
    _draw_black(ax, board_image < 128, (x0, y0), 1.0 / px_per_mm)
    ax.add_patch(Rectangle((x0, y0), bw, bh, facecolor='none', edgecolor='0.7', linewidth=0.3))
    ax.text(MARGIN_MM, h - MARGIN_MM, title, ha='left', va='top', fontsize=12,
            fontweight='bold')
    draw_scale_bar(ax, MARGIN_MM, MARGIN_MM + 18.0)
    ax.text(MARGIN_MM, MARGIN_MM + 15.0, '\n'.join(notes), ha='left', va='top', fontsize=6.5,
            linespacing=1.35)
    return fig
