"""The rules world's fast camera renderer of the ARcube scene: plain NumPy + OpenCV, no
rclpy.

The scene is a floor plane (z = 0), a background wall colour above the horizon, one
ARcube (six faces, each a white square with an ArUco tag centred on it) and optional
flat distractor tags. Faces are planar quads drawn with `cv2.warpPerspective` into
their bounding box only, in painter's order (far to near), after back-face culling;
that is exact for one convex cube plus separate planar tags. Each face gets Lambertian
shading from one directional light; then exposure gain, Gaussian blur and Gaussian
noise are applied to the whole frame.

Frames: poses are 4x4 homogeneous matrices in the world (z up). The camera pose is
the optical frame (z forward, x right, y down). A cube pose places the cube's body
frame (axes through the face centres, faces 0:+x 1:-x 2:+y 3:-y 4:+z 5:-z as in
docs/MODEL.md) at its centre. A tag's own frame is ArUco's: x right, y up in the
marker image, z out of the face; see `FACE_TAG_AXES`.
"""

from dataclasses import dataclass, field

import cv2
import numpy as np

from abp_belief.cube import FACE_NORMALS  # body faces 0:+x 1:-x 2:+y 3:-y 4:+z 5:-z

# "Up" of each tag's image, in the body frame: +z for side faces, -x on the top face
# (so the robot, standing at +x, reads the top tag upright), +x on the bottom face.
_FACE_TAG_UP = np.array(
    [[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 1], [-1, 0, 0], [1, 0, 0]], dtype=float
)
# (6, 3, 3): for each body face, the columns are the tag's x (right), y (up), z (normal).
FACE_TAG_AXES = np.stack(
    [np.column_stack([np.cross(up, n), up, n]) for up, n in zip(_FACE_TAG_UP, FACE_NORMALS)]
)

DEFAULT_EDGE = 0.10
DEFAULT_TAG_EDGE = 0.08
_NEAR = 0.02  # m; quads with a corner closer than this to the camera plane are skipped
_MIP_SIZES = (16, 32, 64, 128, 256, 512)  # square face textures, pixels
_NOISE_BANK_PAD = 32  # pixels of slack around each bank frame for the random window


def face_tag_pose(face, edge=DEFAULT_EDGE):
    """4x4 pose of the tag on a body face, in the cube's body frame (ArUco axes)."""
    pose = np.eye(4)
    pose[:3, :3] = FACE_TAG_AXES[face]
    pose[:3, 3] = FACE_NORMALS[face] * edge / 2
    return pose


def tag_object_points(tag_edge):
    """ArUco corner order (top-left, top-right, bottom-right, bottom-left) in the tag frame;
    what cv2.solvePnP with SOLVEPNP_IPPE_SQUARE expects."""
    h = tag_edge / 2
    return np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], dtype=np.float64)


def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """Optical-frame camera pose (z forward, x right, y down) at `eye` looking at `target`."""
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight along `up`: any right vector will do
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, y, z])
    pose[:3, 3] = eye
    return pose


def _quad_corners(pose, size):
    """World corners (4, 3) of a square of side `size` in the xy-plane of `pose`,
    in texture order: top-left, top-right, bottom-right, bottom-left (y up)."""
    h = size / 2
    local = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]])
    return local @ pose[:3, :3].T + pose[:3, 3]


@dataclass
class FaceView:
    """Ground truth for one cube face as seen from the camera."""

    face: int
    tag_id: int
    cos_view: float          # cos of the angle between the face normal and the line of sight
    corners_px: np.ndarray   # (4, 2) projected tag corners, ArUco order
    area_px: float           # projected area of the tag
    in_image: bool           # all four tag corners inside the image, in front of the camera
    centre_camera: np.ndarray = field(repr=False, default=None)  # tag centre in camera frame


def _project(K, points_cam):
    z = points_cam[:, 2:3]
    uv = points_cam[:, :2] / z
    return uv * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]


def visible_faces(K, width, height, camera_pose, cube_pose, tag_ids=None,
                  edge=DEFAULT_EDGE, tag_edge=DEFAULT_TAG_EDGE, min_cos=0.0):
    """Faces whose outward normal points towards the camera (cos_view > min_cos), with their
    tag's projected corners; sorted by face index. Back faces are never listed."""
    K = np.asarray(K, dtype=float)
    world_to_cam = np.linalg.inv(camera_pose)
    cam_centre = camera_pose[:3, 3]
    out = []
    for face in range(6):
        tag_pose = cube_pose @ face_tag_pose(face, edge)
        centre = tag_pose[:3, 3]
        normal = tag_pose[:3, 2]
        to_cam = cam_centre - centre
        cos_view = float(normal @ to_cam / np.linalg.norm(to_cam))
        if cos_view <= min_cos:
            continue
        corners = _quad_corners(tag_pose, tag_edge)
        corners_cam = corners @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
        centre_cam = world_to_cam[:3, :3] @ centre + world_to_cam[:3, 3]
        if np.any(corners_cam[:, 2] < _NEAR):
            px = np.full((4, 2), np.nan)
            area, inside = 0.0, False
        else:
            px = _project(K, corners_cam)
            area = float(cv2.contourArea(px.astype(np.float32)))
            inside = bool(np.all((px[:, 0] >= 0) & (px[:, 0] <= width - 1)
                                 & (px[:, 1] >= 0) & (px[:, 1] <= height - 1)))
        tag = -1 if tag_ids is None else int(tag_ids[face])
        out.append(FaceView(face, tag, cos_view, px, area, inside, centre_cam))
    return out


@dataclass
class ImageEffects:
    """Photometric effects applied after geometry (all optional)."""

    gain: float = 1.0          # exposure: multiplies intensities before clipping
    blur_sigma: float = 0.0    # Gaussian blur sigma, pixels (0: none)
    noise_std: float = 0.0     # additive Gaussian noise, grey levels (0: none)


@dataclass
class Lighting:
    direction: tuple = (0.3, -0.4, 1.0)  # towards the light, world frame
    ambient: float = 0.45
    diffuse: float = 0.55


@dataclass
class Distractor:
    """A flat tag elsewhere in the scene (pose: tag centre, ArUco axes, z out of the tag)."""

    tag_id: int
    pose: np.ndarray
    size: float = DEFAULT_TAG_EDGE  # tag (black square) side, m
    margin: float = 0.125           # white border, as a fraction of `size` per side


DEFAULT_DICTIONARY = 'DICT_4X4_50'


def tag_dictionary(name):
    """(OpenCV id, number of ids) of the predefined ArUco dictionary `name` (an OpenCV
    name such as 'DICT_4X4_50' or 'DICT_APRILTAG_36h11'); ValueError if there is none."""
    if not (isinstance(name, str) and name.startswith('DICT_') and hasattr(cv2.aruco, name)):
        raise ValueError(f'unknown ArUco dictionary {name!r} (an OpenCV name such as '
                         f'{DEFAULT_DICTIONARY} or DICT_APRILTAG_36h11)')
    dictionary_id = int(getattr(cv2.aruco, name))
    return dictionary_id, len(cv2.aruco.getPredefinedDictionary(dictionary_id).bytesList)


def check_tag_ids(name, tag_ids):
    """ValueError unless `name` is an ArUco dictionary (`tag_dictionary`) that holds every
    id of `tag_ids` that is drawn (ids < 0 are blank faces)."""
    _, size = tag_dictionary(name)
    drawn = [int(t) for t in tag_ids if t >= 0]
    if max(drawn, default=-1) >= size:
        raise ValueError(f'{name} has {size} tag ids, but the tags to draw have ids up to '
                         f'{max(drawn)}')


class ArcubeRenderer:
    """Renders the camera image of an ARcube scene.

    >>> r = ArcubeRenderer(K, 640, 480)
    >>> img = r.render(camera_pose, cube_pose, tag_ids=[0, 1, 2, 3, 4, 5])
    """

    def __init__(self, K, width=640, height=480, dictionary=cv2.aruco.DICT_4X4_50,
                 edge=DEFAULT_EDGE, tag_edge=DEFAULT_TAG_EDGE, encoding='mono8',
                 effects=None, lighting=None, floor_level=120, background_level=170,
                 face_level=235, supersample=4, seed=0, noise_bank=0):
        if encoding not in ('mono8', 'bgr8'):
            raise ValueError(f"encoding must be 'mono8' or 'bgr8', not {encoding!r}")
        if not 0 < tag_edge < edge:
            raise ValueError('tag_edge must be positive and smaller than the cube edge')
        self.K = np.asarray(K, dtype=float)
        self.width, self.height = int(width), int(height)
        self.dictionary_id = dictionary
        self.dictionary = cv2.aruco.getPredefinedDictionary(dictionary)
        self.edge, self.tag_edge = float(edge), float(tag_edge)
        self.encoding = encoding
        self.effects = effects if effects is not None else ImageEffects()
        self.lighting = lighting if lighting is not None else Lighting()
        self.floor_level = float(floor_level)
        self.background_level = float(background_level)
        self.face_level = float(face_level)  # white of a fully lit face (paper is not 255)
        self.supersample = max(1, int(supersample))
        self.rng = np.random.default_rng(seed)
        # noise_bank > 0: image noise from that many pre-drawn frames (random window each
        # time) instead of fresh Gaussian noise per frame; 0: fresh noise (exact, slower).
        self.noise_bank = max(0, int(noise_bank))
        self._noise_frames, self._noise_key = None, None
        self._textures = {}  # (tag_id, margin fraction) -> list of mip levels (uint8)
        light = np.asarray(self.lighting.direction, dtype=float)
        self._light = light / np.linalg.norm(light)

    # -- textures ---------------------------------------------------------------------------

    def _mips(self, tag_id, margin):
        """Face texture pyramid: white square, tag of side (1 - 2 margin) centred."""
        key = (int(tag_id), round(float(margin), 6))
        mips = self._textures.get(key)
        if mips is None:
            top = _MIP_SIZES[-1]
            tex = np.full((top, top), 255, np.uint8)
            tag_px = int(round(top * (1 - 2 * margin)))
            off = (top - tag_px) // 2
            if tag_id >= 0:
                marker = cv2.aruco.generateImageMarker(self.dictionary, int(tag_id), tag_px)
                tex[off:off + tag_px, off:off + tag_px] = marker
            # Area-averaged smaller levels keep far tags anti-aliased (a poor man's mipmap).
            mips = [cv2.resize(tex, (s, s), interpolation=cv2.INTER_AREA) for s in _MIP_SIZES[:-1]]
            mips.append(tex)
            self._textures[key] = mips
        return mips

    # -- geometry ---------------------------------------------------------------------------

    def _shade(self, normal_world):
        lam = max(0.0, float(normal_world @ self._light))
        return self.lighting.ambient + self.lighting.diffuse * lam

    def _cube_quads(self, cam_centre, cube_pose, tag_ids):
        margin = (1 - self.tag_edge / self.edge) / 2
        quads = []
        for face in range(6):
            pose = cube_pose @ face_tag_pose(face, self.edge)
            normal, centre = pose[:3, 2], pose[:3, 3]
            if normal @ (cam_centre - centre) <= 0:  # back face
                continue
            quads.append((pose, self.edge, int(tag_ids[face]), margin))
        return quads

    def _draw_floor(self, img, world_to_cam):
        """Floor z = 0 as one big polygon clipped at the near plane; the rest is wall."""
        cam = np.linalg.inv(world_to_cam)[:3, 3]
        half = 50.0
        square = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]])
        square[:, :2] += cam[:2]
        pts = square @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
        clipped = _clip_near(pts, _NEAR)
        if len(clipped) >= 3:
            px = _project(self.K, clipped)
            px = np.clip(px, -1e5, 1e5)
            cv2.fillConvexPoly(img, np.round(px * 16).astype(np.int32), float(self.floor_level),
                               lineType=cv2.LINE_AA, shift=4)

    def _draw_quad(self, img, world_to_cam, pose, size, tag_id, margin):
        corners = _quad_corners(pose, size) @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
        if np.any(corners[:, 2] < _NEAR):
            return
        px = _project(self.K, corners)
        x0, y0 = np.floor(px.min(axis=0)).astype(int)
        x1, y1 = np.ceil(px.max(axis=0)).astype(int) + 1
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, self.width), min(y1, self.height)
        if x0 >= x1 or y0 >= y1:
            return
        ss = self.supersample
        side = ss * float(np.max(np.linalg.norm(px - np.roll(px, 1, axis=0), axis=1)))
        mips = self._mips(tag_id, margin)
        # Texture level nearest the on-screen size (log scale): bilinear sampling then
        # neither skips texels nor magnifies much.
        level = int(np.argmin(np.abs(np.log2(np.asarray(_MIP_SIZES) / max(side, 1.0)))))
        tex = mips[level]
        s = tex.shape[0]
        shade = self._shade(pose[:3, 2]) * self.face_level / 255.0
        tex = cv2.convertScaleAbs(tex, alpha=shade)
        # Texture corners in pixel-centre coordinates, matching _quad_corners' order.
        src = np.array([[-0.5, -0.5], [s - 0.5, -0.5], [s - 0.5, s - 0.5], [-0.5, s - 0.5]],
                       dtype=np.float32)
        w, h = x1 - x0, y1 - y0
        roi = img[y0:y1, x0:x1]
        if ss > 1:
            # Supersample the ROI: anti-aliased face outlines and unbiased tag edges.
            buf = cv2.resize(roi, (w * ss, h * ss), interpolation=cv2.INTER_NEAREST)
        else:
            buf = np.ascontiguousarray(roi)
        dst = (ss * (px - [x0, y0] + 0.5) - 0.5).astype(np.float32)
        H = cv2.getPerspectiveTransform(src, dst)
        # BORDER_TRANSPARENT leaves pixels outside the quad untouched: the warp composites.
        cv2.warpPerspective(tex, H, (w * ss, h * ss), dst=buf, flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_TRANSPARENT)
        if ss > 1:
            buf = cv2.resize(buf, (w, h), interpolation=cv2.INTER_AREA)
        img[y0:y1, x0:x1] = buf

    # -- public -----------------------------------------------------------------------------

    def render(self, camera_pose, cube_pose=None, tag_ids=None, distractors=(), effects=None,
               more_cubes=()):
        """Image (H x W uint8, or H x W x 3 for bgr8) seen from `camera_pose` (4x4 optical
        frame in the world). `cube_pose` None renders no cube; `tag_ids` gives the tag on each
        body face (-1: blank face). `distractors`: Distractor or (id, pose, size) tuples.
        `more_cubes`: further (cube_pose, tag_ids) of a scene of several cubes."""
        camera_pose = np.asarray(camera_pose, dtype=float)
        world_to_cam = _invert(camera_pose)
        cam_centre = camera_pose[:3, 3]
        img = np.full((self.height, self.width), self.background_level, np.uint8)
        self._draw_floor(img, world_to_cam)

        quads = []
        if cube_pose is not None:
            if tag_ids is None or len(tag_ids) != 6:
                raise ValueError('tag_ids must give one tag id per body face (6)')
            quads += self._cube_quads(cam_centre, np.asarray(cube_pose, float), tag_ids)
        for pose, tags in more_cubes:
            if len(tags) != 6:
                raise ValueError('tag_ids must give one tag id per body face (6)')
            quads += self._cube_quads(cam_centre, np.asarray(pose, float), tags)
        for d in distractors:
            if not isinstance(d, Distractor):
                d = Distractor(*d)
            pose = np.asarray(d.pose, dtype=float)
            if np.linalg.det(pose[:3, :3]) <= 0:
                raise ValueError(f'distractor {d.tag_id}: pose rotation is not proper (det <= 0)')
            if pose[:3, 2] @ (cam_centre - pose[:3, 3]) <= 0:
                continue
            full = d.size * (1 + 2 * d.margin)
            quads.append((pose, full, int(d.tag_id), d.margin / (1 + 2 * d.margin)))
        # Painter's order: farthest quad centre first.
        quads.sort(key=lambda q: -float(np.linalg.norm(q[0][:3, 3] - cam_centre)))
        for pose, size, tag_id, margin in quads:
            self._draw_quad(img, world_to_cam, pose, size, tag_id, margin)

        img = self._apply_effects(img, effects if effects is not None else self.effects)
        if self.encoding == 'bgr8':
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        return img

    def visible_faces(self, camera_pose, cube_pose, tag_ids=None, min_cos=0.0):
        return visible_faces(self.K, self.width, self.height, camera_pose, cube_pose, tag_ids,
                             self.edge, self.tag_edge, min_cos)

    def _apply_effects(self, img, fx):
        if fx.gain != 1.0:
            img = cv2.convertScaleAbs(img, alpha=float(fx.gain))
        if fx.blur_sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), float(fx.blur_sigma))
        if fx.noise_std > 0:
            if self.noise_bank > 0:
                noise = self._bank_noise(img.shape, float(fx.noise_std))
            else:
                noise = self.rng.standard_normal(img.shape, dtype=np.float32)
                noise *= float(fx.noise_std)
            img = cv2.add(img, noise, dtype=cv2.CV_8U)
        return img

    def _bank_noise(self, shape, std):
        """A random window of one of `noise_bank` pre-drawn noise frames (a view, no copy):
        ~20x cheaper than fresh Gaussian noise, and the pattern still changes every frame."""
        pad = _NOISE_BANK_PAD
        key = (shape, std)
        if self._noise_key != key:
            frames = self.rng.standard_normal((self.noise_bank, shape[0] + pad, shape[1] + pad),
                                              dtype=np.float32)
            frames *= std
            self._noise_frames, self._noise_key = frames, key
        k, dy, dx = (int(v) for v in self.rng.integers((self.noise_bank, pad + 1, pad + 1)))
        return self._noise_frames[k, dy:dy + shape[0], dx:dx + shape[1]]


def _invert(pose):
    out = np.eye(4)
    rot = pose[:3, :3]
    out[:3, :3] = rot.T
    out[:3, 3] = -rot.T @ pose[:3, 3]
    return out


def _clip_near(points, near):
    """Sutherland-Hodgman clip of a convex polygon (camera frame) to z >= near."""
    out = []
    n = len(points)
    for i in range(n):
        a, b = points[i], points[(i + 1) % n]
        a_in, b_in = a[2] >= near, b[2] >= near
        if a_in:
            out.append(a)
        if a_in != b_in:
            t = (near - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.array(out)
