"""Rendered ARcube scenes with ground truth, for the tests and the perception benchmark.

Uses the sim bridge's renderer (``abp_sim_bridge.flat_renderer``); no rclpy. The robot's
head is aimed by the project's one head-aiming rule (``abp_description.kinematics.look_at``).
The world frame is the robot's base frame: base_link at the origin, z up. The camera sits
above the base origin and looks at the cube (``distance`` from the camera to the
cube centre, ``elevation`` above the horizontal). The cube is placed in its discrete
state (docs/MODEL.md: ``R(up, yaw)`` maps body -> V, V's x points horizontally from
the cube to the robot base), optionally turned by a small yaw error about z.
Distractor tags lie flat on the floor or stand upright beside the cube, far enough
to the side not to overlap it in the image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from abp_belief import cube as cube_model
from abp_description.frames import rot_z
from abp_description.kinematics import look_at as aim_head
from abp_sim_bridge.flat_renderer import (
    FACE_TAG_AXES,
    ArcubeRenderer,
    Distractor,
    ImageEffects,
    look_at,
    tag_object_points,
)

__all__ = ['Scene', 'SceneGenerator', 'TruthTag', 'default_camera']

BORDER_MARGIN_PX = 3.0      # ArUco's default minDistanceToBorder
DEFAULT_K = np.array([[554.256, 0.0, 319.5], [0.0, 554.256, 239.5], [0.0, 0.0, 1.0]])


def default_camera():
    """(K, width, height) of the robot's head camera (abp_description), else the default."""
    try:
        from abp_description import camera_intrinsics
        cam = camera_intrinsics()
        return cam.K, cam.width, cam.height
    except Exception:  # noqa: BLE001 -- description not installed / no yaml: use the default
        return DEFAULT_K.copy(), 640, 480


@dataclass
class TruthTag:
    """A tag that is in the image: id, projected corners, centre and normal (world)."""

    tag_id: int
    corners_px: np.ndarray
    centre: np.ndarray
    normal: np.ndarray
    cos_view: float
    in_image: bool
    on_cube: bool
    face: int = -1
    rotation: np.ndarray = None      # (3, 3) tag axes (ArUco: x right, y up, z out) in world


@dataclass
class Scene:
    image: np.ndarray
    camera_pose: np.ndarray          # optical frame in the world (= base) frame
    cube_pose: np.ndarray            # body frame in the world
    faces: np.ndarray                # tag id per body face
    state: int
    aspect: tuple                    # true aspect key (type, s0, s1, s2)
    tags: list                       # TruthTag for every tag facing the camera
    viewpoint: np.ndarray = field(default_factory=lambda: np.zeros(3))
    distance: float = 0.0
    elevation_deg: float = 0.0

    def expected(self, max_view_angle_deg=90.0):
        """Tags a detector should find: in the image (3 px clear of its border), viewed
        within the angle."""
        c = np.cos(np.deg2rad(max_view_angle_deg))
        return [t for t in self.tags if t.in_image and t.cos_view >= c]


class SceneGenerator:
    """Renders ARcube scenes with the sim bridge's renderer and records the truth."""

    def __init__(self, K=None, width=None, height=None, effects=None, cube_size=0.10,
                 tag_size=0.08, encoding='mono8', supersample=4, seed=0):
        if K is None:
            K, w0, h0 = default_camera()
            width = width or w0
            height = height or h0
        self.K = np.asarray(K, dtype=np.float64)
        self.width, self.height = int(width or 640), int(height or 480)
        self.effects = effects if effects is not None else ImageEffects(
            blur_sigma=0.6, noise_std=2.0)
        self.cube_size, self.tag_size = float(cube_size), float(tag_size)
        self.renderer = ArcubeRenderer(self.K, self.width, self.height, edge=cube_size,
                                       tag_edge=tag_size, encoding=encoding,
                                       effects=self.effects, supersample=supersample,
                                       seed=seed)
        self.rng = np.random.default_rng(seed)

    def cube_pose(self, state, centre, viewpoint=(0.0, 0.0, 0.0), yaw_error_deg=0.0):
        """Body -> world pose of a cube in `state` at `centre`, V facing `viewpoint`."""
        centre = np.asarray(centre, dtype=np.float64)
        to_robot = np.asarray(viewpoint, dtype=np.float64) - centre
        yaw_v = np.arctan2(to_robot[1], to_robot[0])
        pose = np.eye(4)
        pose[:3, :3] = rot_z(yaw_v + np.deg2rad(yaw_error_deg)) @ cube_model.state_rotation(state)
        pose[:3, 3] = centre
        return pose

    def render(self, faces, state, distance=1.0, elevation_deg=35.0, bearing_deg=0.0,
               yaw_error_deg=0.0, look_offset=(0.0, 0.0), distractors=(), effects=None):
        """One scene. `bearing_deg`: direction of the cube from the base; `look_offset`:
        where the cube appears, as fractions of the half image (x right, y down)."""
        e = np.deg2rad(elevation_deg)
        b = np.deg2rad(bearing_deg)
        h = self.cube_size
        horizontal = distance * np.cos(e)
        centre = np.array([horizontal * np.cos(b), horizontal * np.sin(b), h / 2])
        eye = np.array([0.0, 0.0, h / 2 + distance * np.sin(e)])
        cam = look_at(eye, centre)
        # Shift the view so that the cube appears at look_offset in the image.
        ox, oy = look_offset
        ray = np.array([-ox * (self.width / 2) / self.K[0, 0],
                        -oy * (self.height / 2) / self.K[1, 1], 1.0])
        target = eye + cam[:3, :3] @ ray
        cam = look_at(eye, eye + (target - eye) * distance)
        scene = self.render_view(cam, faces, state, centre, yaw_error_deg, distractors, effects)
        scene.distance, scene.elevation_deg = float(distance), float(elevation_deg)
        return scene

    def render_view(self, camera_pose, faces, state, centre, yaw_error_deg=0.0,
                    distractors=(), effects=None, viewpoint=(0.0, 0.0, 0.0)):
        """A scene seen from a given camera pose (optical frame in the world = base frame),
        the cube centred at `centre` in `state` with V facing `viewpoint`."""
        faces = np.asarray(faces, dtype=np.int64)
        camera_pose = np.asarray(camera_pose, dtype=np.float64)
        pose = self.cube_pose(state, centre, viewpoint, yaw_error_deg)
        image = self.renderer.render(camera_pose, pose, faces, distractors=list(distractors),
                                     effects=effects)
        tags = self._truth(camera_pose, pose, faces, distractors)
        aspect = cube_model.aspect_of(faces, state)
        dist = float(np.linalg.norm(np.asarray(centre, float) - camera_pose[:3, 3]))
        return Scene(image, camera_pose, pose, faces, int(state), aspect, tags,
                     np.asarray(viewpoint, dtype=np.float64), dist, 0.0)

    def render_robot(self, kinematics, faces, state, centre, yaw_error_deg=0.0,
                     distractors=(), effects=None, q=None):
        """A scene seen by the robot's head camera: base_link at the origin, the head
        panned and tilted (``abp_description.kinematics.look_at``, from `q` or the neutral
        pose) to the cube centre. Returns (scene, q)."""
        q, _ = aim_head(kinematics, kinematics.neutral() if q is None else q, centre)
        scene = self.render_view(kinematics.camera_pose(q), faces, state, centre,
                                 yaw_error_deg, distractors, effects)
        cam = scene.camera_pose[:3, 3]
        to_cube = np.asarray(centre, float) - cam
        scene.elevation_deg = float(np.degrees(np.arctan2(-to_cube[2],
                                                          np.hypot(to_cube[0], to_cube[1]))))
        return scene, q

    def random_distractors(self, n, n_tags, centre_distance, elevation_deg, bearing_deg=0.0,
                           in_range=None):
        """`n` distractor tags beside the cube (0.2-0.45 m to its side, random ids: the
        first `in_range` in 0..n_tags-1, the rest outside; default half and half)."""
        e = np.deg2rad(elevation_deg)
        b = np.deg2rad(bearing_deg)
        horizontal = centre_distance * np.cos(e)
        centre = np.array([horizontal * np.cos(b), horizontal * np.sin(b), 0.0])
        side = np.array([-np.sin(b), np.cos(b), 0.0])
        towards = -np.array([np.cos(b), np.sin(b), 0.0])
        in_range = (n + 1) // 2 if in_range is None else int(in_range)
        out = []
        for k in range(n):
            sign = 1.0 if k % 2 == 0 else -1.0
            lateral = sign * self.rng.uniform(0.2, 0.45) * max(1.0, centre_distance / 1.5)
            along = self.rng.uniform(-0.15, 0.15)
            pos = centre + lateral * side + along * towards
            if k < in_range:
                tag_id = int(self.rng.integers(0, n_tags))
            else:
                tag_id = int(self.rng.integers(n_tags, 50))
            pose = np.eye(4)
            if self.rng.random() < 0.5:                       # flat on the floor, z up
                pose[:3, :3] = rot_z(self.rng.uniform(-np.pi, np.pi))
                pos[2] = 0.0005
            else:                                             # upright, facing the robot
                yaw = np.arctan2(-towards[1], -towards[0]) + np.pi + self.rng.uniform(-0.6, 0.6)
                z = np.array([np.cos(yaw), np.sin(yaw), 0.0])
                y = np.array([0.0, 0.0, 1.0])
                pose[:3, :3] = np.column_stack([np.cross(y, z), y, z])
                pos[2] = 0.06
            pose[:3, 3] = pos
            out.append(Distractor(tag_id, pose, self.tag_size))
        return out

    def _inside(self, px, margin=BORDER_MARGIN_PX):
        px = np.asarray(px, dtype=np.float64)
        return bool(np.isfinite(px).all()
                    and np.all((px[:, 0] >= margin) & (px[:, 0] <= self.width - 1 - margin)
                               & (px[:, 1] >= margin) & (px[:, 1] <= self.height - 1 - margin)))

    def _truth(self, cam, cube_pose, faces, distractors):
        tags = []
        for fv in self.renderer.visible_faces(cam, cube_pose, faces):
            world = cube_pose[:3, :3] @ (cube_model.FACE_NORMALS[fv.face] * self.cube_size / 2) \
                + cube_pose[:3, 3]
            tags.append(TruthTag(int(fv.tag_id), fv.corners_px, world,
                                 cube_pose[:3, :3] @ cube_model.FACE_NORMALS[fv.face],
                                 float(fv.cos_view), self._inside(fv.corners_px), True,
                                 int(fv.face), cube_pose[:3, :3] @ FACE_TAG_AXES[fv.face]))
        world_to_cam = np.linalg.inv(cam)
        for d in distractors:
            pose = np.asarray(d.pose, dtype=np.float64)
            centre, normal = pose[:3, 3], pose[:3, 2]
            to_cam = cam[:3, 3] - centre
            cos_view = float(normal @ to_cam / np.linalg.norm(to_cam))
            if cos_view <= 0:
                continue
            pts = tag_object_points(d.size) @ pose[:3, :3].T + centre
            pc = pts @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
            if np.any(pc[:, 2] <= 0.02):
                continue
            px = pc[:, :2] / pc[:, 2:3] * [self.K[0, 0], self.K[1, 1]] \
                + [self.K[0, 2], self.K[1, 2]]
            tags.append(TruthTag(int(d.tag_id), px, centre, normal, cos_view,
                                 self._inside(px), False, -1, pose[:3, :3].copy()))
        return tags

