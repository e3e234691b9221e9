"""A table, one ARcube and a camera that does not move, on MuJoCo (plain Python, no rclpy):
the world of the scripted operator (`scripted_operator_node`, start_graph.sh --operator
scripted). No robot body: a person's hands stand in for the skills.

The frame is `base_link` of the operator graph (docs/OPERATOR.md): on the table below the
camera, x towards the cube, z up. The camera stands at `camera_pose` [x, y, z, roll, pitch,
yaw] (m, deg; camera body x forward, z up, positive pitch looks down), the same values the
detector gets as `fixed_camera_pose`. The cube rests where the camera's optical axis meets
the height of its centre (or at `cube_xy`).

The cube is moved by *setting its pose* (`place`), not by simulated hands: the scripted
operator computes where a person's action leaves it (`scripted_operator.ManualOutcome`) and
puts it there, resting on the table. MuJoCo renders the camera's view (the same scene
pieces as the sim bridge's world: `mujoco_scene`'s cube with its tag textures and heavy
slab, floor and lights).
"""

import numpy as np

from abp_belief.cube import STATE_ROTATIONS, state_of
from abp_description import camera_intrinsics
from abp_description.frames import rot_z_deg

from .flat_renderer import DEFAULT_DICTIONARY
from .mujoco_scene import CUBE_BODY, CubeSpec, _add_cube, add_room, mujoco, rendered_as
from .mujoco_world import EGL_HINT, discrete_state

CAMERA_NAME = 'fixed_camera'
# ROS optical frame (z forward, x right, y down) in the camera body (x forward, y left, z up).
OPTICAL_IN_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# MuJoCo cameras look along -z with y up: their frame is the optical frame turned 180 deg
# about its x axis.
MUJOCO_CAMERA_IN_OPTICAL = np.diag([1.0, -1.0, -1.0])


def _rotation_xyz(roll_deg, pitch_deg, yaw_deg):
    """Rz(yaw) Ry(pitch) Rx(roll): fixed-axis x, y, z angles (abp_perception.camera_model's
    `fixed_camera_pose`, scipy's 'xyz')."""
    r, p, y = np.radians([roll_deg, pitch_deg, yaw_deg])
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


def optical_pose(camera_pose):
    """4x4 pose of the camera's optical frame in base_link from [x, y, z, roll, pitch, yaw]
    (m, deg of the camera body); ValueError for another length or a non-finite value."""
    values = [float(v) for v in camera_pose]
    if len(values) != 6 or not np.all(np.isfinite(values)):
        raise ValueError('camera_pose must be [x, y, z, roll, pitch, yaw] (m, deg), got '
                         f'{values}')
    pose = np.eye(4)
    pose[:3, :3] = _rotation_xyz(*values[3:]) @ OPTICAL_IN_BODY
    pose[:3, 3] = values[:3]
    return pose


def cube_spot(camera_pose, edge):
    """(x, y) where the optical axis meets the height of a resting cube's centre; ValueError
    when the camera does not look down at the table in front of it."""
    pose = optical_pose(camera_pose)
    origin, axis = pose[:3, 3], pose[:3, 2]
    height = edge / 2
    if axis[2] >= -1e-6 or origin[2] <= height:
        raise ValueError('camera_pose: the camera must stand above the cube and look down '
                         f'(positive pitch), got {list(camera_pose)}')
    t = (height - origin[2]) / axis[2]
    spot = origin + t * axis
    if np.hypot(*spot[:2]) < edge:
        raise ValueError('camera_pose: the camera looks at the spot below itself; the cube '
                         'must stand in front of the base frame (x towards it)')
    return spot[:2]


def view_frame(cube_xy):
    """Columns x_V (from the cube towards base_link's origin, horizontal), y_V, z_V = up."""
    to_base = -np.asarray(cube_xy, dtype=float)
    x_v = np.array([*to_base, 0.0]) / np.linalg.norm(to_base)
    return np.column_stack([x_v, np.cross([0.0, 0.0, 1.0], x_v), [0.0, 0.0, 1.0]])


class OperatorWorld:
    """Floor, lights, the ARcube and a fixed camera. `hidden`: scenario.HiddenModel (face
    tags, heavy face); the cube starts at `cube_xy` (None: where the camera looks) with
    body face `up_face` up, turned `yaw_deg` about the vertical."""

    def __init__(self, hidden, camera_pose, *, cube_xy=None, up_face=4, yaw_deg=0.0,
                 edge=0.10, tag_edge=0.08, cube_mass=0.75, heavy_mass_ratio=0.625,
                 width=None, height=None, dictionary=DEFAULT_DICTIONARY):
        self.hidden = hidden
        self.edge = float(edge)
        self.camera_pose = optical_pose(camera_pose)
        self.home_xy = (cube_spot(camera_pose, self.edge) if cube_xy is None
                        else np.asarray(cube_xy, dtype=float).reshape(2))
        intr = camera_intrinsics()
        self.width, self.height = int(width or intr.width), int(height or intr.height)
        self.fovy = float(np.degrees(2 * np.arctan(intr.height / (2 * intr.fy))))
        heavy = hidden.mass_index - 1 if hidden.mass_index > 0 else None
        self.cube_spec = CubeSpec(position=(*self.home_xy, self.edge / 2),
                                  face_tags=tuple(hidden.face_tags), edge=self.edge,
                                  tag_edge=tag_edge, mass=cube_mass, heavy_face=heavy,
                                  heavy_mass_ratio=heavy_mass_ratio, dictionary=dictionary)
        self.model = self._build()
        self.data = mujoco.MjData(self.model)
        self._cube_qadr = self.model.joint(
            self.model.body(CUBE_BODY).jntadr[0]).qposadr[0]
        self._cube_body = self.model.body(CUBE_BODY).id
        self._renderer = None
        rotation = view_frame(self.home_xy) @ STATE_ROTATIONS[state_of(up_face, 0)]
        self.place(self.home_xy, rot_z_deg(float(yaw_deg)) @ rotation)

    def _build(self):
        spec = mujoco.MjSpec()
        spec.modelname = 'abp_operator_scene'
        spec.visual.quality.shadowsize = 0
        spec.visual.quality.offsamples = 0
        spec.visual.global_.offwidth = max(self.width, 640)
        spec.visual.global_.offheight = max(self.height, 480)
        add_room(spec, shadows=False)
        world = spec.worldbody
        quat = np.zeros(4)
        camera_rot = self.camera_pose[:3, :3] @ MUJOCO_CAMERA_IN_OPTICAL
        mujoco.mju_mat2Quat(quat, np.ascontiguousarray(camera_rot).ravel())
        world.add_camera(name=CAMERA_NAME, pos=list(self.camera_pose[:3, 3]), quat=list(quat),
                         fovy=self.fovy)
        _add_cube(spec, self.cube_spec)
        return spec.compile()

    # -- the cube -------------------------------------------------------------------------
    def cube_pose(self):
        """4x4 pose of the cube's body frame in base_link."""
        out = np.eye(4)
        out[:3, :3] = self.data.xmat[self._cube_body].reshape(3, 3)
        out[:3, 3] = self.data.xpos[self._cube_body]
        return out

    def discrete_state(self):
        """MODEL.md's (up, yaw) of the cube as the camera's base_link sees it."""
        return discrete_state(self.cube_pose(), (0.0, 0.0, 0.0))

    def view_frame(self):
        return view_frame(self.cube_pose()[:2, 3])

    def place(self, xy, rotation):
        """Put the cube at rest on the table at `xy` with `rotation` (body -> base_link);
        its centre at half an edge above the table (a 45-deg yaw leaves it flat too)."""
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rotation, dtype=float).ravel())
        adr = self._cube_qadr
        self.data.qpos[adr:adr + 3] = [float(xy[0]), float(xy[1]), self.edge / 2]
        self.data.qpos[adr + 3:adr + 7] = quat
        self.data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)

    # -- the camera -----------------------------------------------------------------------
    def render(self, encoding='mono8'):
        """The camera's image (HxWx3 RGB / BGR, or HxW mono8). The first call creates the
        GL context in the calling thread: call it from one thread only."""
        if self._renderer is None:
            try:
                self._renderer = mujoco.Renderer(self.model, self.height, self.width)
            except Exception as error:  # noqa: BLE001 -- any GL failure means the same
                raise RuntimeError(f'{EGL_HINT} ({type(error).__name__}: {error})') from None
        self._renderer.update_scene(self.data, camera=CAMERA_NAME)
        return rendered_as(self._renderer.render(), encoding)

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


__all__ = ['CAMERA_NAME', 'OperatorWorld', 'cube_spot', 'optical_pose', 'view_frame']
