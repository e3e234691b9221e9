"""Printable ARcube nets: which body face goes where on the paper, with its tag turned how,
where the fold lines and glue tabs are, and whether it fits on a sheet (plain NumPy, no
drawing; `printable_pages` draws a `CubePage`).

The net is a cross, printed side out: the front face (body +x) in the middle, the top
(+z) above it, the bottom (-z) and the back (-x) below, the left (-y) and right (+y)
wings beside it. Folding the squares away from the reader puts every face where the
body frame of docs/MODEL.md says, and every tag turns as the sim bridge's renderers draw
it (`abp_sim_bridge.flat_renderer.FACE_TAG_AXES`: tag up is +z on the side faces, -x on
the top, +x on the bottom), so a printed cube is the cube the sim renders. On the paper
the tags of the front, top, bottom and wings read upright and the back's upside down.

Page coordinates are millimetres, origin at the sheet's bottom-left corner, y up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from abp_belief.cube import FACE_NAMES, FACE_NORMALS, MASS_NAMES, NUM_FACES
from abp_sim_bridge.flat_renderer import FACE_TAG_AXES

PAPER_MM = {'a4': (210.0, 297.0), 'letter': (215.9, 279.4)}
MARGIN_MM = 10.0          # printers leave 3-6 mm blank; 10 mm is safe on any of them
HEADER_MM = 14.0          # model name and sizes
FOOTER_MM = 34.0          # scale bar and instructions
SCALE_BAR_MM = 100.0      # 10 cm: measure it to check the printer did not rescale
MAX_TAB_MM = 10.0         # glue tab depth (at most a fifth of the cube edge)
ROOT_FACE = 0             # the front, body +x, in the middle of the cross

# The cross as grid cells (column, row), row 0 at the top: the root in the middle.
CROSS_CELLS = ((1, 1), (1, 0), (0, 1), (2, 1), (1, 2), (1, 3))
# Sides of a square: outward direction on the paper (x right, y up).
SIDES = {'right': (1, 0), 'up': (0, 1), 'left': (-1, 0), 'down': (0, -1)}


class NetDoesNotFit(ValueError):
    """The net of a cube of this size is larger than the printable part of the sheet."""


@dataclass(frozen=True)
class Square:
    """One face square of the net."""

    face: int                  # body face 0:+x 1:-x 2:+y 3:-y 4:+z 5:-z
    cell: tuple                # (column, row) in the cross, row 0 at the top
    paper_right: np.ndarray    # body-frame direction of the paper's +x on this square
    paper_up: np.ndarray       # body-frame direction of the paper's +y
    quarter_turns: int         # the tag image turned this many quarter turns anticlockwise

    def neighbour_face(self, side: str) -> int:
        """Body face across one side of this square once folded."""
        dx, dy = SIDES[side]
        return face_of_normal(dx * self.paper_right + dy * self.paper_up)


@dataclass(frozen=True)
class Tab:
    """A glue tab on one side of a square; it goes under the face `under_face`."""

    cell: tuple
    side: str
    under_face: int


def face_of_normal(normal) -> int:
    hit = np.flatnonzero(np.abs(FACE_NORMALS - np.asarray(normal)).sum(axis=1) < 1e-9)
    if hit.size != 1:
        raise ValueError(f'{normal} is not a face normal')
    return int(hit[0])


def _quarter_turns(paper_right, paper_up, face) -> int:
    """Quarter turns (anticlockwise on the paper) of the tag image on this square: the
    turn that brings the image's right onto the face's tag-right axis."""
    tag_right = FACE_TAG_AXES[face][:, 0]
    on_paper = (float(tag_right @ paper_right), float(tag_right @ paper_up))
    return {(1.0, 0.0): 0, (0.0, 1.0): 1, (-1.0, 0.0): 2, (0.0, -1.0): 3}[on_paper]


def cross_squares() -> list[Square]:
    """The six squares of the cross, unfolded from the root by rolling over each fold.

    A square shows its face from outside: paper right x paper up = the face's outward
    normal. Rolling over a side onto the next square (folded away from the reader) turns
    that side's direction into the next face's normal and the old normal into the
    direction pointing back across the fold.
    """
    right, up = FACE_TAG_AXES[ROOT_FACE][:, 0], FACE_TAG_AXES[ROOT_FACE][:, 1]
    frames = {CROSS_CELLS[0]: (right, up)}
    todo = [CROSS_CELLS[0]]
    while todo:
        col, row = todo.pop(0)
        a, b = frames[(col, row)]
        c = np.cross(a, b)
        steps = {(col + 1, row): (-c, b), (col - 1, row): (c, b),
                 (col, row - 1): (a, -c), (col, row + 1): (a, c)}
        for cell, frame in steps.items():
            if cell in CROSS_CELLS and cell not in frames:
                frames[cell] = frame
                todo.append(cell)
    squares = []
    for cell in CROSS_CELLS:
        a, b = frames[cell]
        face = face_of_normal(np.cross(a, b))
        squares.append(Square(face, cell, a, b, _quarter_turns(a, b, face)))
    assert sorted(s.face for s in squares) == list(range(NUM_FACES))
    return squares


def _neighbour_cell(cell, side):
    dx, dy = SIDES[side]
    return (cell[0] + dx, cell[1] - dy)           # rows count downwards


def fold_lines(squares) -> list[tuple[tuple, str]]:
    """(cell, side) of every fold between two squares, each once."""
    cells = {s.cell for s in squares}
    return [(s.cell, side) for s in squares for side in ('right', 'down')
            if _neighbour_cell(s.cell, side) in cells]


def glue_tabs(squares) -> list[Tab]:
    """One tab per cube edge that the net cuts (7 for any net): the two cut sides of that
    edge are glued, one carrying the tab. The tab goes where it stays inside the cross's
    bounding box (an empty cell of the grid) when one of the two can."""
    cells = {s.cell for s in squares}
    cols = [c for c, _ in cells]
    rows = [r for _, r in cells]
    by_edge = {}
    for s in squares:
        for side in SIDES:
            if _neighbour_cell(s.cell, side) not in cells:
                key = frozenset((s.face, s.neighbour_face(side)))
                by_edge.setdefault(key, []).append((s, side))
    tabs = []
    for pair in by_edge.values():
        assert len(pair) == 2, pair

        def inside(item):
            col, row = _neighbour_cell(item[0].cell, item[1])
            return min(cols) <= col <= max(cols) and min(rows) <= row <= max(rows)

        carrier, other = sorted(pair, key=lambda item: not inside(item))
        tabs.append(Tab(carrier[0].cell, carrier[1], other[0].face))
    return tabs


def marker_modules(dictionary_id: int, tag_id: int) -> np.ndarray:
    """The tag as a boolean grid of modules (True = black), black border included, row 0
    at the top of the tag image."""
    dictionary = cv2.aruco.getPredefinedDictionary(dictionary_id)
    n = dictionary.markerSize + 2
    if not 0 <= tag_id < dictionary.bytesList.shape[0]:
        raise ValueError(f'tag id {tag_id} is not in the dictionary (0..'
                         f'{dictionary.bytesList.shape[0] - 1})')
    return cv2.aruco.generateImageMarker(dictionary, int(tag_id), n, borderBits=1) < 128


@dataclass
class PlacedSquare:
    """One face square where it is printed on the page."""

    face: int                  # body face 0:+x 1:-x 2:+y 3:-y 4:+z 5:-z
    tag_id: int
    origin: tuple              # bottom-left corner, mm
    modules: np.ndarray        # tag modules as printed (already turned), row 0 at the top
    quarter_turns: int         # as on this face's square of the cross net


@dataclass(kw_only=True)
class CubeSheet:
    """What every printed sheet of a cube says, in page millimetres: a net (`CubePage`)
    or a sheet of tiles (`cube_tiles.TilePage`)."""

    name: str
    faces: tuple               # tag id on body faces +x -x +y -y +z -z
    mass_index: int
    paper: str
    size_mm: tuple
    cube_mm: float
    tag_mm: float
    dictionary: str
    scale_bar: tuple           # (x0, y0): left end of the bar's bottom edge; SCALE_BAR_MM long
    heavy_face: int | None = None
    weight_mark: tuple | None = None   # centre of the weight mark on the heavy face, mm
    notes: list = field(default_factory=list)


@dataclass(kw_only=True)
class CubePage(CubeSheet):
    """Everything `printable_pages.draw_cube_page` draws."""

    squares: list
    folds: list                # ((x0, y0), (x1, y1)) segments
    cuts: list                 # ((x0, y0), (x1, y1)) segments of the outline
    tabs: list                 # (polygon (k, 2), label, label centre, label angle deg)


def parse_model_name(name: str) -> tuple[tuple, int]:
    """(tags on body faces +x -x +y -y +z -z, mass index) of 'c<t0>-...-<t5>/<mass>'
    (mass: u, m+x, m-x, m+y, m-y, m+z, m-z; docs/MODEL.md)."""
    try:
        tags, mass_name = name.split('/')
        if not tags.startswith('c'):
            raise ValueError
        faces = tuple(int(t) for t in tags[1:].split('-'))
    except ValueError:
        raise ValueError(f"{name!r} is not a model name like 'c0-4-1-2-3-6/u' or "
                         "'c0-1-2-4-5-3/m+y'") from None
    if mass_name not in MASS_NAMES:
        raise ValueError(f'{name!r}: mass {mass_name!r} is not one of {", ".join(MASS_NAMES)}')
    if len(faces) != NUM_FACES or len(set(faces)) != NUM_FACES or min(faces) < 0:
        raise ValueError(f'{name!r}: a cube needs 6 distinct tag ids >= 0, one per body face '
                         '(+x -x +y -y +z -z)')
    return faces, MASS_NAMES.index(mass_name)


def tab_depth(cube_mm: float) -> float:
    return min(MAX_TAB_MM, 0.2 * cube_mm)


def _net_extent(cube_mm: float) -> tuple[float, float, float, float]:
    """(min x, min y, max x, max y) of the cross with its tabs, root cell's corner at 0."""
    squares = cross_squares()
    t = tab_depth(cube_mm)
    xs, ys = [], []
    for s in squares:
        x0, y0 = s.cell[0] * cube_mm, -s.cell[1] * cube_mm
        xs += [x0, x0 + cube_mm]
        ys += [y0, y0 + cube_mm]
    for tab in glue_tabs(squares):
        poly = _tab_polygon((tab.cell[0] * cube_mm, -tab.cell[1] * cube_mm), cube_mm, t,
                            tab.side)
        xs += list(poly[:, 0])
        ys += list(poly[:, 1])
    return min(xs), min(ys), max(xs), max(ys)


def printable_box(paper: str) -> tuple[float, float]:
    """(width, height) mm available for the net on a sheet."""
    w, h = PAPER_MM[paper]
    return w - 2 * MARGIN_MM, h - 2 * MARGIN_MM - HEADER_MM - FOOTER_MM


def largest_cube_mm(paper: str) -> float:
    """Largest cube edge (0.1 mm steps) whose net fits on the sheet."""
    lo, hi = 1.0, 1000.0
    while hi - lo > 0.05:
        mid = (lo + hi) / 2
        x0, y0, x1, y1 = _net_extent(mid)
        bw, bh = printable_box(paper)
        lo, hi = (mid, hi) if (x1 - x0 <= bw and y1 - y0 <= bh) else (lo, mid)
    return np.floor(lo * 10) / 10


def check_sizes(cube_mm: float, tag_mm: float, paper: str):
    if paper not in PAPER_MM:
        raise ValueError(f'paper must be one of {", ".join(PAPER_MM)}, got {paper!r}')
    if not 0 < tag_mm < cube_mm:
        raise ValueError(f'the tag ({tag_mm:g} mm) must be smaller than the cube face '
                         f'({cube_mm:g} mm)')


def dictionary_id(dictionary: str) -> int:
    """OpenCV's id of an ArUco dictionary name like 'DICT_4X4_50' (ValueError if unknown)."""
    if not hasattr(cv2.aruco, dictionary) or not dictionary.startswith('DICT_'):
        raise ValueError(f'unknown ArUco dictionary {dictionary!r} (an OpenCV name like '
                         'DICT_4X4_50)')
    return getattr(cv2.aruco, dictionary)


def check_fits(cube_mm: float, tag_mm: float, paper: str):
    check_sizes(cube_mm, tag_mm, paper)
    x0, y0, x1, y1 = _net_extent(cube_mm)
    bw, bh = printable_box(paper)
    if x1 - x0 > bw or y1 - y0 > bh:
        best = largest_cube_mm(paper)
        ratio = tag_mm / cube_mm
        raise NetDoesNotFit(
            f'the net of a {cube_mm:g} mm cube is {x1 - x0:.0f} x {y1 - y0:.0f} mm with its '
            f'glue tabs, but {paper.upper()} leaves {bw:.0f} x {bh:.0f} mm for it (margins, '
            f'title, scale bar): the largest cube that fits is {best:g} mm. Print a smaller '
            f'cube, e.g. --cube-size {best / 1000:g} --tag-size {ratio * best / 1000:.4g} '
            "(same tag-to-face ratio), and set the detector's cube_size and marker_size "
            "(and the aspect matcher's cube_size) to the same values; or print the six "
            'faces on separate squares for a solid cube or box (--layout tiles).')


def _tab_polygon(origin, cube_mm, depth, side) -> np.ndarray:
    """Trapezoid on one side of the square at `origin` (bottom-left), tapered at 45 deg so
    that tabs meeting at a corner do not overlap; base first."""
    x, y, e, t = origin[0], origin[1], cube_mm, depth
    return np.array({
        'right': [(x + e, y), (x + e, y + e), (x + e + t, y + e - t), (x + e + t, y + t)],
        'left': [(x, y + e), (x, y), (x - t, y + t), (x - t, y + e - t)],
        'up': [(x + e, y + e), (x, y + e), (x + t, y + e + t), (x + e - t, y + e + t)],
        'down': [(x, y), (x + e, y), (x + e - t, y - t), (x + t, y - t)],
    }[side], dtype=float)


def _side_segment(origin, cube_mm, side):
    x, y, e = origin[0], origin[1], cube_mm
    return {'right': ((x + e, y), (x + e, y + e)), 'left': ((x, y), (x, y + e)),
            'up': ((x, y + e), (x + e, y + e)), 'down': ((x, y), (x + e, y))}[side]


def cube_page(name: str, faces, mass_index: int, *, cube_mm: float, tag_mm: float,
              paper: str = 'a4', dictionary: str = 'DICT_4X4_50') -> CubePage:
    """The page of one model (NetDoesNotFit / ValueError with a clear message)."""
    check_fits(cube_mm, tag_mm, paper)
    dictionary_number = dictionary_id(dictionary)
    squares = cross_squares()
    page_w, page_h = PAPER_MM[paper]
    x0, y0, x1, y1 = _net_extent(cube_mm)
    bw, bh = printable_box(paper)
    # Centre the net in the box between the title and the footer.
    box_bottom = MARGIN_MM + FOOTER_MM
    dx = MARGIN_MM + (bw - (x1 - x0)) / 2 - x0
    dy = box_bottom + (bh - (y1 - y0)) / 2 - y0

    def origin(cell):
        return (dx + cell[0] * cube_mm, dy - cell[1] * cube_mm)

    placed = []
    for s in squares:
        modules = np.rot90(marker_modules(dictionary_number, faces[s.face]), s.quarter_turns)
        placed.append(PlacedSquare(s.face, int(faces[s.face]), origin(s.cell), modules,
                                   s.quarter_turns))
    folds = [_side_segment(origin(cell), cube_mm, side) for cell, side in fold_lines(squares)]
    tabs, cuts = [], []
    t = tab_depth(cube_mm)
    tab_sides = set()
    for tab in glue_tabs(squares):
        poly = _tab_polygon(origin(tab.cell), cube_mm, t, tab.side)
        folds.append((tuple(poly[0]), tuple(poly[1])))
        cuts += [(tuple(poly[i]), tuple(poly[i + 1])) for i in (1, 2)] + \
            [(tuple(poly[3]), tuple(poly[0]))]
        angle = {'right': 90.0, 'left': 90.0, 'up': 0.0, 'down': 0.0}[tab.side]
        tabs.append((poly, f'glue under tag {faces[tab.under_face]}', tuple(poly.mean(axis=0)),
                     angle))
        tab_sides.add((tab.cell, tab.side))
    cells = {s.cell for s in squares}
    for s in squares:
        for side in SIDES:
            if _neighbour_cell(s.cell, side) not in cells and (s.cell, side) not in tab_sides:
                cuts.append(_side_segment(origin(s.cell), cube_mm, side))
    heavy = None if mass_index == 0 else mass_index - 1
    weight_mark = None
    if heavy is not None:
        # In the white border below the tag (as printed), clear of the tag's quiet zone.
        sq = next(p for p in placed if p.face == heavy)
        margin = (cube_mm - tag_mm) / 2
        weight_mark = (sq.origin[0] + cube_mm / 2, sq.origin[1] + margin / 2)
    page = CubePage(name=name, faces=tuple(int(f) for f in faces), mass_index=int(mass_index),
                    paper=paper, size_mm=(page_w, page_h), cube_mm=cube_mm, tag_mm=tag_mm,
                    dictionary=dictionary, squares=placed, folds=folds, cuts=cuts, tabs=tabs,
                    scale_bar=(MARGIN_MM, MARGIN_MM + FOOTER_MM - 12.0), heavy_face=heavy,
                    weight_mark=weight_mark)
    page.notes = _notes(page)
    return page


def _notes(page: CubePage) -> list[str]:
    faces = ' '.join(f'{FACE_NAMES[f]}:{page.faces[f]}' for f in range(NUM_FACES))
    notes = [
        f"Tags by body face {faces} ({page.dictionary}); the small grey number in a face's "
        'corner is its tag id.',
        'Print at 100 % ("actual size", no fit to page) and check the bar measures 10 cm. '
        'Cut the solid lines, fold the dashed ones',
        'away from you (print outside), glue each tab under the face whose tag it names. '
        'Thin card (160-250 g/m2) keeps the faces flat.',
    ]
    return notes + weight_notes(page.faces, page.mass_index, 'cube')


def weight_notes(faces, mass_index: int, thing: str) -> list[str]:
    """Where the weight goes in a `thing` ('cube', 'box') of this mass variant."""
    if mass_index == 0:
        return [f'Uniform mass ({MASS_NAMES[0]}): leave the {thing} empty, or put a weight '
                'at its very centre.']
    f = mass_index - 1
    return [
        f'Eccentric mass ({MASS_NAMES[mass_index]}): before closing the {thing}, tape a '
        f'weight flat against the inside of the face marked W ({FACE_NAMES[f]}, tag '
        f'{faces[f]}), centred',
        f'on it: the heavier the better, at least several times the empty {thing} '
        '(the simulated cube: 62 % of its mass in a slab against that face).']


__all__ = ['CROSS_CELLS', 'CubePage', 'CubeSheet', 'NetDoesNotFit', 'PAPER_MM', 'PlacedSquare',
           'SCALE_BAR_MM', 'Square', 'Tab', 'check_fits', 'check_sizes', 'cross_squares',
           'cube_page', 'dictionary_id', 'fold_lines', 'glue_tabs', 'largest_cube_mm',
           'marker_modules', 'parse_model_name', 'printable_box', 'weight_notes']
