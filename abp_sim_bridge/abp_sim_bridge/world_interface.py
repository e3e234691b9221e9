"""What both simulated worlds (rules and MuJoCo) share with the sim_bridge node: the
contact event they report and how they take commands (plain Python, no rclpy).
"""

from dataclasses import dataclass

import numpy as np


@dataclass
class ContactEvent:
    """A manual action the world recognised from the hands' contacts with the cube."""

    action: str        # 'PUSH', 'LIFT', 'FLIP', or '' (a contact that is no action)
    effect: str        # slid, pivoted, rotated, unchanged, missed, slipped, ...
    detail: str = ''

    @property
    def is_action(self):
        return bool(self.action)

    def __str__(self):
        head = f'{self.action} {self.effect}' if self.action else self.effect
        return f'{head}: {self.detail}' if self.detail else head


class CommandInputs:
    """The command side of a world: the last /cmd_vel and the controllers' trajectories.

    A world using it sets `time_ns`, `q`, `qd` and `controllers` ({name: (follower,
    joint indices)})."""

    cmd = None              # (v, w) of the last /cmd_vel
    cmd_time_ns = None

    @property
    def time(self):
        return self.time_ns * 1e-9

    def set_cmd_vel(self, v, w):
        v, w = float(v), float(w)
        if not (np.isfinite(v) and np.isfinite(w)):
            raise ValueError('cmd_vel must be finite')
        self.cmd = (v, w)
        self.cmd_time_ns = self.time_ns

    def set_trajectory(self, controller, joint_names, points, stamp_s=0.0):
        """Start a trajectory on a controller (see joint_trajectory_follower)."""
        follower, idx = self.controllers[controller]
        return follower.set_trajectory(joint_names, points, stamp_s, self.time,
                                       self.q[idx], self.qd[idx])


__all__ = ['CommandInputs', 'ContactEvent']
