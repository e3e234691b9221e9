"""make_cubes round trip (issue 35): a printed page of every mass variant, read back from
its 300 dpi PNG with OpenCV's ArUco detector, shows the six tags of its model, and the net
folded along its fold lines is the model's cube with every tag turned as the sim's
renderers draw it; the PDF is one page of the right size; the scale bar is 10 cm. Every
page of the robot set has the same net (cube_net.cross_squares) with its own tags: each
page's layout places the model's tags on the squares, turned as on the printed pages.
Tiles (the faces as separate squares, the default when the net does not fit): every id
is found on the sheets, each tag turned as on the net's page, and each edge's label names
the face the model's cube has across that edge.

In-process: make_cubes.main writes the files, the round-trip checks read only the files.
"""

import re
import struct
import zlib

import cv2
import matplotlib.pyplot as plt
import numpy as np
import pytest

from abp_belief import population
from abp_belief.cube import FACE_NAMES, FACE_NORMALS, OPPOSITE_FACE
from abp_bench import cube_net, cube_tiles, make_cubes, printable_pages
from abp_sim_bridge.flat_renderer import FACE_TAG_AXES

CUBE_M, TAG_M = 0.05, 0.04        # the 10 cm default does not fit on one sheet (test below)
DPI = 300
PX_PER_MM = DPI / 25.4
ROBOT = population.robot_set()
# The printed pages: one model of the robot set in its seven mass variants (uniform and a
# weight mark on each face). Writing all 30 pages took ~15 s; the other models' pages
# differ only in which tag sits on which square (test_every_robot_model_page_...).
PRINTED = [f'c0-1-2-4-5-3/{mass}' for mass in ('u', 'm+x', 'm-x', 'm+y', 'm-y', 'm+z', 'm-z')]


@pytest.fixture(scope='module')
def robot_pages(tmp_path_factory):
    out = tmp_path_factory.mktemp('cubes')
    assert make_cubes.main([*PRINTED, '--out', str(out), '--cube-size', str(CUBE_M),
                            '--tag-size', str(TAG_M), '--charuco']) == 0
    return out


def detect(image):
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    corners, ids, _ = cv2.aruco.ArucoDetector(dictionary).detectMarkers(image)
    return ([] if ids is None else ids.ravel().tolist()), corners


def _snap(v):
    """A paper direction (x right, y up) snapped to the nearest axis, as a 3-vector."""
    v = np.asarray(v, float) / np.linalg.norm(v)
    axis = np.array([(1, 0), (0, 1), (-1, 0), (0, -1)])[np.argmax(
        [v @ a for a in ((1, 0), (0, 1), (-1, 0), (0, -1))])]
    assert np.degrees(np.arccos(np.clip(v @ axis, -1, 1))) < 2.0, v
    return np.array([axis[0], axis[1], 0.0])


def _quarter_fold(direction):
    """Rotation folding a square lying beyond a hinge in paper `direction` away from the
    reader (into -z): +90 deg about z x direction."""
    axis = np.cross([0.0, 0.0, 1.0], direction)
    rotation, _ = cv2.Rodrigues(axis * np.pi / 2)
    return rotation


def fold_net(ids, corners):
    """{tag: (cell, R)} of the detected tags: grid cell from the tag centres and the
    rotation of each square once the net is folded, the first square unmoved."""
    cube_px = CUBE_M * 1000 * PX_PER_MM
    centres = np.array([c.reshape(4, 2).mean(axis=0) for c in corners])
    cells = np.round((centres - centres.min(axis=0)) / cube_px).astype(int)
    assert np.abs((centres - centres.min(axis=0)) / cube_px - cells).max() < 0.02
    cell_of = {tuple(cell): i for i, cell in enumerate(cells)}
    frames = {0: np.eye(3)}
    todo = [0]
    while todo:
        i = todo.pop()
        for step in ((1, 0), (-1, 0), (0, 1), (0, -1)):          # image x right, y down
            j = cell_of.get((cells[i][0] + step[0], cells[i][1] + step[1]))
            if j is not None and j not in frames:
                direction = np.array([step[0], -step[1], 0.0])  # on the paper, y up
                frames[j] = frames[i] @ _quarter_fold(direction)
                todo.append(j)
    assert len(frames) == 6, 'the net falls apart'
    return cells, frames


def test_printed_pages_detect_and_fold_into_their_cubes(robot_pages):
    printed = [(name, faces) for name, faces in zip(ROBOT.names, ROBOT.faces)
               if name in PRINTED]
    assert len(printed) == len(PRINTED)
    for name, faces in printed:
        image = cv2.imread(str(robot_pages / f'{make_cubes.file_stem(name)}.png'),
                           cv2.IMREAD_GRAYSCALE)
        assert image is not None, name
        assert abs(image.shape[1] - 210 * PX_PER_MM) < 1.5
        assert abs(image.shape[0] - 297 * PX_PER_MM) < 1.5
        ids, corners = detect(image)
        faces = [int(t) for t in faces]
        assert sorted(ids) == sorted(faces), f'{name}: detected {sorted(ids)}'
        cells, frames = fold_net(ids, corners)
        # Across every fold line: the two tags are on adjacent faces of the model's cube.
        folds = 0
        for i in range(6):
            for j in range(i + 1, 6):
                if np.abs(cells[i] - cells[j]).sum() == 1:
                    fi, fj = faces.index(ids[i]), faces.index(ids[j])
                    assert fj != OPPOSITE_FACE[fi], f'{name}: tags {ids[i]}, {ids[j]} fold ' \
                        'together but are on opposite faces of the model'
                    folds += 1
        assert folds == 5
        # The folded net is the model: one rotation takes every printed tag's right, up
        # and outward normal onto its body face's tag axes (FACE_TAG_AXES, the renderers').
        rotations = []
        for i, tag in enumerate(ids):
            tl, tr, _, bl = corners[i].reshape(4, 2)
            right = _snap((tr - tl) * [1, -1])
            up = _snap((tl - bl) * [1, -1])
            folded = frames[i] @ np.column_stack([right, up, np.cross(right, up)])
            rotations.append(FACE_TAG_AXES[faces.index(tag)] @ folded.T)
        for q in rotations:
            assert np.allclose(q, rotations[0], atol=1e-9), f'{name}: tags turned wrongly'
        assert np.isclose(np.linalg.det(rotations[0]), 1.0)


def test_every_robot_model_page_places_its_tags_as_the_printed_pages():
    """Each of the 30 pages --model-set robot asks for: its six tags on the squares of their
    body faces, turned as on the printed pages (read back above), the weight mark on the
    heavy face's square."""
    args = make_cubes.build_parser().parse_args(['--model-set', 'robot', '--out', 'unused'])
    models = make_cubes._models(args)
    assert [name for name, _, _ in models] == list(ROBOT.names) and len(models) == 30
    dictionary = cv2.aruco.DICT_4X4_50
    printed = cube_net.cube_page(PRINTED[0], *cube_net.parse_model_name(PRINTED[0]),
                                 cube_mm=CUBE_M * 1000, tag_mm=TAG_M * 1000)
    turns = {sq.face: (sq.origin, sq.quarter_turns) for sq in printed.squares}
    for name, faces, mass in models:
        page = cube_net.cube_page(name, faces, mass, cube_mm=CUBE_M * 1000, tag_mm=TAG_M * 1000)
        assert sorted(sq.face for sq in page.squares) == list(range(6)), name
        for sq in page.squares:
            assert sq.tag_id == faces[sq.face], name
            assert (sq.origin, sq.quarter_turns) == turns[sq.face], name
            assert np.array_equal(sq.modules, np.rot90(
                cube_net.marker_modules(dictionary, sq.tag_id), sq.quarter_turns)), name
        assert page.heavy_face == (None if mass == 0 else mass - 1), name
        if page.heavy_face is not None:
            heavy = next(sq for sq in page.squares if sq.face == page.heavy_face)
            assert heavy.origin[0] < page.weight_mark[0] < heavy.origin[0] + page.cube_mm


def _png_dpi(path):
    data = path.read_bytes()
    k = data.index(b'pHYs')
    x, y, unit = struct.unpack('>IIB', data[k + 4:k + 13])
    assert unit == 1
    return x * 0.0254, y * 0.0254


def _bar_px(image, page):
    """Length in pixels of the scale bar drawn at page.scale_bar."""
    x0, y0 = page.scale_bar
    row = int(round((page.size_mm[1] - (y0 + 0.75)) * PX_PER_MM))
    dark = image[row] < 128
    middle = int(round((x0 + 50) * PX_PER_MM))
    left, right = middle, middle
    while dark[left - 1]:
        left -= 1
    while dark[right + 1]:
        right += 1
    return right - left + 1


def test_scale_bar_and_files(robot_pages):
    name = 'c0-1-2-4-5-3/m+y'
    stem = robot_pages / make_cubes.file_stem(name)
    assert _png_dpi(stem.with_suffix('.png')) == pytest.approx((DPI, DPI), abs=0.01)
    image = cv2.imread(str(stem.with_suffix('.png')), cv2.IMREAD_GRAYSCALE)
    page = cube_net.cube_page(name, *cube_net.parse_model_name(name), cube_mm=CUBE_M * 1000,
                              tag_mm=TAG_M * 1000)
    assert abs(_bar_px(image, page) - 100 * PX_PER_MM) <= 1.5    # 1181 px = 10 cm at 300 dpi
    # The weight mark (a grey disc, white W) sits in the heavy face's square, on the paper.
    heavy = next(s for s in page.squares if s.face == page.heavy_face)
    mx, my = page.weight_mark
    assert heavy.origin[0] < mx < heavy.origin[0] + page.cube_mm
    assert heavy.origin[1] < my < heavy.origin[1] + (page.cube_mm - page.tag_mm) / 2
    disc = image[int(round((page.size_mm[1] - my) * PX_PER_MM)),
                 int(round((mx - 0.25 * (page.cube_mm - page.tag_mm) / 2) * PX_PER_MM))]
    assert 60 < disc < 200
    assert any('tag 2' in line and 'W' in line for line in page.notes)   # +y carries tag 2
    pdf = stem.with_suffix('.pdf').read_bytes()
    _check_pdf(pdf, (210, 297))


def _check_pdf(pdf: bytes, size_mm, pages=1):
    assert pdf.startswith(b'%PDF-') and pdf.rstrip().endswith(b'%%EOF')
    assert len(re.findall(rb'/Type\s*/Page\b', pdf)) == pages
    boxes = re.findall(rb'/MediaBox\s*\[([^\]]*)\]', pdf)
    assert len(boxes) == pages
    for found in boxes:
        box = [float(v) for v in found.split()]
        assert box[:2] == [0, 0]
        assert box[2:] == pytest.approx([s / 25.4 * 72 for s in size_mm], abs=0.01)
    # Every stream inflates (a truncated file would not).
    for m in re.finditer(rb'/FlateDecode.*?stream\r?\n', pdf, re.S):
        zlib.decompressobj().decompress(pdf[m.end():m.end() + 200])


def test_letter_paper_and_the_charuco_board(robot_pages, tmp_path):
    assert make_cubes.main(['c0-4-1-2-3-6/u', '--out', str(tmp_path), '--paper', 'letter',
                            '--cube-size', str(CUBE_M), '--tag-size', str(TAG_M)]) == 0
    _check_pdf((tmp_path / 'c0-4-1-2-3-6_u.pdf').read_bytes(), (215.9, 279.4))
    image = cv2.imread(str(tmp_path / 'c0-4-1-2-3-6_u.png'), cv2.IMREAD_GRAYSCALE)
    assert sorted(detect(image)[0]) == [0, 1, 2, 3, 4, 6]
    # The board page: every ChArUco corner found on the printed board.
    from abp_perception.charuco_calibration import BoardSpec
    spec = BoardSpec()
    board = cv2.imread(str(robot_pages / 'charuco_board.png'), cv2.IMREAD_GRAYSCALE)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(spec.board()).detectBoard(board)
    assert ids is not None and len(ids) == (spec.squares_x - 1) * (spec.squares_y - 1)
    _check_pdf((robot_pages / 'charuco_board.pdf').read_bytes(), (210, 297))


def test_refusals_write_nothing(tmp_path, capsys):
    out = tmp_path / 'none'
    # The detector's default 10 cm cube: its net is 30 x 41 cm (auto prints tiles instead).
    assert make_cubes.main(['c0-4-1-2-3-6/u', '--out', str(out), '--layout', 'net']) == 1
    err = capsys.readouterr().err
    assert 'A4 leaves' in err and 'largest cube that fits is' in err and 'cube_size' in err
    assert '--layout tiles' in err
    assert not out.exists()
    # A face larger than the printable part of the sheet does not tile either.
    assert make_cubes.main(['c0-4-1-2-3-6/u', '--out', str(out), '--cube-size', '0.25',
                            '--tag-size', '0.2']) == 1
    assert 'one face of a 250 mm cube does not fit on A4' in capsys.readouterr().err
    assert not out.exists()
    for bad in (['c0-4-1-2-3/u'], ['c0-4-1-2-3-6/m+w'], ['c0-4-1-2-3-3/u'], []):
        assert make_cubes.main([*bad, '--out', str(out), '--cube-size', '0.05',
                                '--tag-size', '0.04']) == 2
        assert not out.exists()
    assert make_cubes.main(['c0-4-1-2-3-6/u', '--out', str(out), '--cube-size', '0.05',
                            '--tag-size', '0.05']) == 2
    assert 'smaller than the cube face' in capsys.readouterr().err


def test_fold_geometry_matches_the_belief_cube():
    """The cross's squares, fold lines and tabs: 6 faces, 5 folds, 7 tabs on the 7 cut
    edges, each tab going under a face adjacent to its own."""
    squares = cube_net.cross_squares()
    assert sorted(s.face for s in squares) == list(range(6))
    assert len(cube_net.fold_lines(squares)) == 5
    tabs = cube_net.glue_tabs(squares)
    assert len(tabs) == 7
    face_at = {s.cell: s.face for s in squares}
    edges = {frozenset((face_at[t.cell], t.under_face)) for t in tabs}
    assert len(edges) == 7
    assert all(OPPOSITE_FACE[a] != b for a, b in map(tuple, edges))


# --- Tiles: the six faces as separate squares (--layout tiles; auto when the net does not
# fit). At the detector's default sizes (10 cm cube, 8 cm tag), two faces per A4 sheet.
TILED = ['c0-1-2-4-5-3/m+y', 'c0-4-1-2-3-6/u']
SIDE_DIRECTIONS = {'right': (1, 0), 'up': (0, 1), 'left': (-1, 0), 'down': (0, -1)}


@pytest.fixture(scope='module')
def tiled_pages(tmp_path_factory):
    out = tmp_path_factory.mktemp('tiles')
    assert make_cubes.main([*TILED, '--out', str(out)]) == 0       # defaults: no --layout
    return out


def _quarter_turns(right_on_paper) -> int:
    """Quarter turns (anticlockwise) that bring the tag image's right onto this paper axis."""
    return [(1, 0), (0, 1), (-1, 0), (0, -1)].index(tuple(int(v) for v in right_on_paper[:2]))


def _printed_tags(image, size_mm):
    """{tag id: (centre mm, paper right, paper up)} of the tags detected on a page image."""
    ids, corners = detect(image)
    tags = {}
    for tag, quad in zip(ids, corners):
        tl, tr, _, bl = quad.reshape(4, 2)
        cx, cy = quad.reshape(4, 2).mean(axis=0)
        centre = (cx / PX_PER_MM, size_mm[1] - cy / PX_PER_MM)
        assert tag not in tags, f'tag {tag} twice on one page'
        tags[tag] = (centre, _snap((tr - tl) * [1, -1]), _snap((tl - bl) * [1, -1]))
    return tags


def _drawn_labels(page):
    """(text, position mm, rotation deg) of every text drawn on a tile page's figure (the
    figure make_cubes saves as that page)."""
    fig = printable_pages.draw_tile_page(page)
    try:
        return [(t.get_text(), t.get_position(), t.get_rotation() % 360)
                for t in fig.axes[0].texts]
    finally:
        plt.close(fig)


def test_tiled_pages_detect_every_tag_with_its_neighbours(tiled_pages, robot_pages):
    # The rotation of each body face's tag in the one-piece net, read back from its page.
    net_name = PRINTED[0]
    net_faces = list(cube_net.parse_model_name(net_name)[0])
    net_image = cv2.imread(str(robot_pages / f'{make_cubes.file_stem(net_name)}.png'),
                           cv2.IMREAD_GRAYSCALE)
    net_turns = {net_faces.index(tag): _quarter_turns(right) for tag, (_, right, _) in
                 _printed_tags(net_image, (210, 297)).items()}
    assert sorted(net_turns) == list(range(6))
    for name in TILED:
        faces, mass = cube_net.parse_model_name(name)
        faces = list(faces)
        stem = tiled_pages / make_cubes.file_stem(name)
        _check_pdf(stem.with_suffix('.pdf').read_bytes(), (210, 297), pages=3)
        layout = cube_tiles.tile_pages(name, faces, mass, cube_mm=100.0, tag_mm=80.0)
        assert len(layout) == 3 and [len(p.tiles) for p in layout] == [2, 2, 2]
        found = {}
        for k, page in enumerate(layout, start=1):
            png = tiled_pages / f'{make_cubes.file_stem(name)}_page{k}.png'
            assert _png_dpi(png) == pytest.approx((DPI, DPI), abs=0.01)
            image = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
            assert abs(image.shape[1] - 210 * PX_PER_MM) < 1.5
            assert abs(image.shape[0] - 297 * PX_PER_MM) < 1.5
            assert abs(_bar_px(image, page) - 100 * PX_PER_MM) <= 1.5, f'{name} page {k}'
            tags = _printed_tags(image, page.size_mm)
            assert not set(tags) & set(found), f'{name}: a tag on two pages'
            found.update(tags)
            labels = _drawn_labels(page)
            for tag, (centre, right, up) in tags.items():
                face = faces.index(tag)
                # The tag sits centred on its tile, turned as in the one-piece net.
                tile = next(t for t in page.tiles if t.tag_id == tag)
                assert np.allclose(centre, np.add(tile.origin, 50.0), atol=0.5), (name, tag)
                assert _quarter_turns(right) == net_turns[face], f'{name}: tag {tag} turned'
                # Every edge's label names the face across it on the model's cube: the
                # paper direction of that edge, carried onto the body by the detected tag's
                # right and up (the renderers' tag axes on this face).
                x0, y0 = tile.origin
                inside = [(text, pos, rot) for text, pos, rot in labels
                          if x0 < pos[0] < x0 + 100 and y0 < pos[1] < y0 + 100]
                assert f'{FACE_NAMES[face]}, id {tag}' in [text for text, _, _ in inside]
                edges = [(text, pos, rot) for text, pos, rot in inside
                         if text.startswith('meets')]
                assert len(edges) == 4, (name, tag, edges)
                met = set()
                for text, (px, py), rotation in edges:
                    gaps = {'left': px - x0, 'right': x0 + 100 - px, 'down': py - y0,
                            'up': y0 + 100 - py}
                    side = min(gaps, key=gaps.get)
                    assert gaps[side] < 10.0, (name, tag, text)     # in the border, off the tag
                    assert rotation == (0.0 if side in ('up', 'down') else
                                        (90.0 if side == 'left' else 270.0))
                    a, b = np.array([*SIDE_DIRECTIONS[side], 0.0]) @ np.array([right, up]).T
                    body = a * FACE_TAG_AXES[face][:, 0] + b * FACE_TAG_AXES[face][:, 1]
                    other = int(np.argmax(FACE_NORMALS @ body))
                    assert np.allclose(FACE_NORMALS[other], body), body
                    assert text == f'meets {FACE_NAMES[other]} (id {faces[other]})', \
                        f'{name}: tag {tag} {side}: {text}'
                    met.add(other)
                assert met == set(range(6)) - {face, int(OPPOSITE_FACE[face])}
            if page.heavy_face is not None and page.weight_mark is not None:
                mx, my = page.weight_mark
                heavy = next(t for t in page.tiles if t.face == page.heavy_face)
                assert heavy.origin[0] < mx < heavy.origin[0] + 100
                disc = image[int(round((page.size_mm[1] - my) * PX_PER_MM)),
                             int(round((mx - 1.5) * PX_PER_MM))]
                assert 60 < disc < 200, f'{name}: no weight mark'
        assert sorted(found) == sorted(faces), f'{name}: found {sorted(found)}'
        marked = [p for p in layout if p.weight_mark is not None]
        assert len(marked) == (0 if mass == 0 else 1)
        assert all(any('W' in line for line in p.notes) for p in layout) == (mass != 0)


def test_tile_layout_fits_the_sheet_and_forced_tiles(tmp_path):
    assert cube_tiles.tile_grid(100.0, 'a4') == (1, 2)
    assert cube_tiles.tile_grid(100.0, 'letter') == (1, 2)
    assert cube_tiles.tile_grid(50.0, 'a4') == (3, 4)
    for paper in ('a4', 'letter'):
        bw, bh = cube_net.printable_box(paper)
        for page in cube_tiles.tile_pages('c0-4-1-2-3-6/u', (0, 4, 1, 2, 3, 6), 0,
                                          cube_mm=100.0, tag_mm=80.0, paper=paper):
            for tile in page.tiles:
                x, y = tile.origin
                assert cube_net.MARGIN_MM <= x and x + 100 <= cube_net.MARGIN_MM + bw
                bottom = cube_net.MARGIN_MM + cube_net.FOOTER_MM
                assert bottom <= y and y + 100 <= bottom + bh
    # A net that fits can still be tiled on request: one sheet of six 5 cm faces.
    assert make_cubes.main(['c0-4-1-2-3-6/u', '--out', str(tmp_path), '--layout', 'tiles',
                            '--cube-size', str(CUBE_M), '--tag-size', str(TAG_M)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ['c0-4-1-2-3-6_u.pdf',
                                                         'c0-4-1-2-3-6_u_page1.png']
    image = cv2.imread(str(tmp_path / 'c0-4-1-2-3-6_u_page1.png'), cv2.IMREAD_GRAYSCALE)
    assert sorted(detect(image)[0]) == [0, 1, 2, 3, 4, 6]
