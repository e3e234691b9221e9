"""Printable ARcube faces as separate squares ("tiles"), for covering a solid cube or box
when the one-piece net (`cube_net`) does not fit on a sheet: the detector's default 10 cm
cube has a 30 x 41 cm net but two 10 cm faces fit on an A4 or Letter page (three pages).

Each tile is its body face's square of the cross net, cut loose: the same tag turned the
same way (`cube_net.cross_squares`), so an edge of the tile meets the same face of the
cube as the same edge of the square in the net, and is labelled with it ("meets +z (id
5)"). Gluing every tile with each edge against the face it names builds the cube the
sim renders, as folding the net does. Plain NumPy, no drawing: `printable_pages` draws
a `TilePage`. Page coordinates are millimetres, origin at the sheet's bottom-left, y up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from abp_belief.cube import FACE_NAMES, NUM_FACES

from .cube_net import (
    FOOTER_MM,
    MARGIN_MM,
    PAPER_MM,
    SIDES,
    CubeSheet,
    NetDoesNotFit,
    PlacedSquare,
    check_sizes,
    cross_squares,
    dictionary_id,
    marker_modules,
    printable_box,
    weight_notes,
)

TILE_GAP_MM = 6.0          # between tiles: room for the scissors


@dataclass
class Tile(PlacedSquare):
    """One face square on a tile page: a square of the net, cut out on its own, that says
    which face each side meets."""

    meets: dict                # side ('right', 'up', 'left', 'down') -> body face across it


@dataclass(kw_only=True)
class TilePage(CubeSheet):
    """One sheet of tiles: everything `printable_pages.draw_tile_page` draws."""

    tiles: list
    number: int                # 1-based page number
    page_count: int


def face_label(face: int, tag_id: int) -> str:
    return f'{FACE_NAMES[face]}, id {tag_id}'


def edge_label(face: int, tag_id: int) -> str:
    return f'meets {FACE_NAMES[face]} (id {tag_id})'


def tile_grid(cube_mm: float, paper: str) -> tuple[int, int]:
    """(columns, rows) of tiles that fit in the printable box of a sheet."""
    bw, bh = printable_box(paper)
    return (max(0, int((bw + TILE_GAP_MM) // (cube_mm + TILE_GAP_MM))),
            max(0, int((bh + TILE_GAP_MM) // (cube_mm + TILE_GAP_MM))))


def tile_pages(name: str, faces, mass_index: int, *, cube_mm: float, tag_mm: float,
               paper: str = 'a4', dictionary: str = 'DICT_4X4_50') -> list[TilePage]:
    """The sheets of one model's six tiles, in body face order, as many per sheet as fit
    (NetDoesNotFit / ValueError with a clear message)."""
    check_sizes(cube_mm, tag_mm, paper)
    dictionary_number = dictionary_id(dictionary)
    cols, rows = tile_grid(cube_mm, paper)
    if cols * rows == 0:
        bw, bh = printable_box(paper)
        raise NetDoesNotFit(
            f'one face of a {cube_mm:g} mm cube does not fit on {paper.upper()}, which '
            f'leaves {bw:.0f} x {bh:.0f} mm (margins, title, scale bar): the largest cube '
            f'whose faces print one per sheet is {min(bw, bh):.0f} mm.')
    per_sheet = cols * rows
    squares = sorted(cross_squares(), key=lambda s: s.face)
    chunks = [squares[k:k + per_sheet] for k in range(0, NUM_FACES, per_sheet)]
    page_w, page_h = PAPER_MM[paper]
    bw, bh = printable_box(paper)
    heavy = None if mass_index == 0 else mass_index - 1
    margin = (cube_mm - tag_mm) / 2
    pages = []
    for number, chunk in enumerate(chunks, start=1):
        used_cols = min(cols, len(chunk))
        used_rows = -(-len(chunk) // used_cols)
        grid_w = used_cols * cube_mm + (used_cols - 1) * TILE_GAP_MM
        grid_h = used_rows * cube_mm + (used_rows - 1) * TILE_GAP_MM
        # Centred in the box between the title and the footer, filled row by row from the top.
        left = MARGIN_MM + (bw - grid_w) / 2
        top = MARGIN_MM + FOOTER_MM + (bh + grid_h) / 2
        tiles, weight_mark = [], None
        for k, s in enumerate(chunk):
            col, row = k % used_cols, k // used_cols
            origin = (left + col * (cube_mm + TILE_GAP_MM),
                      top - (row + 1) * cube_mm - row * TILE_GAP_MM)
            modules = np.rot90(marker_modules(dictionary_number, faces[s.face]),
                               s.quarter_turns)
            tiles.append(Tile(s.face, int(faces[s.face]), origin, modules, s.quarter_turns,
                              {side: s.neighbour_face(side) for side in SIDES}))
            if s.face == heavy:
                # The border's top-right corner: the edge labels take the middle of each side.
                weight_mark = (origin[0] + cube_mm - margin / 2, origin[1] + cube_mm - margin / 2)
        page = TilePage(name=name, faces=tuple(int(f) for f in faces),
                        mass_index=int(mass_index), paper=paper, size_mm=(page_w, page_h),
                        cube_mm=cube_mm, tag_mm=tag_mm, dictionary=dictionary, tiles=tiles,
                        number=number, page_count=len(chunks),
                        scale_bar=(MARGIN_MM, MARGIN_MM + FOOTER_MM - 12.0), heavy_face=heavy,
                        weight_mark=weight_mark)
        page.notes = _notes(page)
        pages.append(page)
    return pages


def _notes(page: TilePage) -> list[str]:
    faces = ' '.join(f'{FACE_NAMES[f]}:{page.faces[f]}' for f in range(NUM_FACES))
    here = ', '.join(face_label(t.face, t.tag_id) for t in page.tiles)
    notes = [
        f'Page {page.number} of {page.page_count}: faces {here}. Tags by body face {faces} '
        f'({page.dictionary}).',
        'Print at 100 % ("actual size", no fit to page) and check the bar measures 10 cm. '
        'Cut out each square along its solid outline and glue it',
        f'on a solid cube or box of {page.cube_mm:g} mm, tag outside, each edge against the '
        'face it names ("meets +z (id 5)": the face carrying tag 5).',
    ]
    return notes + weight_notes(page.faces, page.mass_index, 'box')


__all__ = ['TILE_GAP_MM', 'Tile', 'TilePage', 'edge_label', 'face_label', 'tile_grid',
           'tile_pages']
