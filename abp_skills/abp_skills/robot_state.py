"""The robot state the skills act on, and whether it is recent enough (plain code, no rclpy).

`RobotState` keeps the latest joint positions, the odometry pose (x, y, yaw) and the cube
pose estimate, each with the time it arrived on the injected clock `now` (the node's
clock). The estimate is stored in the odom frame, so that a cube seen before the base
moved is still found after it (`cube` moves it back into base_link with the latest
odometry). The readers raise `skill_checks.Refused` with the reason a skill reports when
a value is missing or older than its limit. Thread-safe: the node's callbacks write while
the skills read.
"""

import threading
import time

import numpy as np

from abp_description.frames import se2_between, se2_compose

from .skill_checks import Refused


def point_base_to_odom(base_pose, point):
    """A 3-D point in base_link, in the odom frame (z unchanged) from the base pose."""
    x, y, _ = se2_compose(base_pose, (point[0], point[1], 0.0))
    return np.array([x, y, point[2]])


def point_odom_to_base(base_pose, point):
    """A 3-D point in the odom frame, in base_link (z unchanged) from the base pose."""
    x, y, _ = se2_between(base_pose, (point[0], point[1], 0.0))
    return np.array([x, y, point[2]])


class RobotState:
    """Latest joints, odometry and cube estimate with their arrival times.

    `q_from_mapping(positions, default)` turns {joint name: position} into the joint vector
    (RobotKinematics.q_from_mapping: joints missing from a message keep their last value).
    `monotonic` and `sleep` pace the wait for a first message just after start-up."""

    def __init__(self, now, q_from_mapping, monotonic=time.monotonic, sleep=time.sleep):
        self._now = now
        self._q_from_mapping = q_from_mapping
        self._monotonic = monotonic
        self._sleep = sleep
        self._lock = threading.Lock()
        self._q = None              # (13,) latest joint positions
        self._q_time = None
        self._odom = None           # (x, y, yaw)
        self._odom_time = None
        self._estimate = None       # (cube centre in odom (3,), receipt time)

    # -- writers (the node's subscriptions) ------------------------------------------------
    def set_joint_positions(self, positions):
        with self._lock:
            self._q = self._q_from_mapping(positions, default=self._q)
            self._q_time = self._now()

    def set_odom(self, pose):
        with self._lock:
            self._odom = np.asarray(pose, dtype=float).copy()
            self._odom_time = self._now()

    def set_cube_estimate(self, centre_in_base):
        """The cube centre seen now in base_link (kept in odom with the latest odometry)."""
        with self._lock:
            odom = self._odom if self._odom is not None else np.zeros(3)
            self._estimate = (point_base_to_odom(odom, centre_in_base), self._now())

    # -- readers (the skills and the feasibility service) ---------------------------------
    def latest_joints(self):
        """The latest joint positions whatever their age, or None."""
        with self._lock:
            return None if self._q is None else self._q.copy()

    def _wait_fresh(self, attribute, max_age_s, max_wait_s):
        """Give a sensor topic up to `max_wait_s` wall seconds to deliver a value younger
        than `max_age_s`: just after start-up (discovery), or when this process was
        starved of CPU and its callbacks lag the sim clock on a loaded machine."""
        deadline = self._monotonic() + max_wait_s
        while self._monotonic() < deadline:
            with self._lock:
                value, stamp = getattr(self, attribute), getattr(self, attribute + '_time')
            if value is not None and self._now() - stamp <= max_age_s:
                return
            self._sleep(0.02)

    def joints(self, max_age_s, wait=True, first_wait_s=None):
        """The joint positions; Refused when none arrived or they are too old. `wait`:
        when none arrived yet or the latest is too old, wait up to `first_wait_s` wall
        seconds (default `max_age_s`) for a fresh one."""
        if wait:
            self._wait_fresh('_q', max_age_s, max_age_s if first_wait_s is None else first_wait_s)
        with self._lock:
            q, stamp = self._q, self._q_time
        if q is None:
            raise Refused('refused: no /joint_states received')
        age = self._now() - stamp
        if age > max_age_s:
            raise Refused(f'refused: /joint_states is {age:.1f} s old')
        return q.copy()

    def base_pose(self, max_age_s, required=True, first_wait_s=None):
        """The odometry pose (x, y, yaw); when missing or too old: Refused if `required`
        (after waiting up to `first_wait_s`, default `max_age_s`, wall seconds for a first
        fresh one), else None (a skill under way reads it without waiting)."""
        if required:
            self._wait_fresh('_odom', max_age_s,
                             max_age_s if first_wait_s is None else first_wait_s)
        with self._lock:
            pose, stamp = self._odom, self._odom_time
        if pose is None or self._now() - stamp > max_age_s:
            if required:
                raise Refused('refused: no recent /odom' if pose is None else
                              f'refused: /odom is {self._now() - stamp:.1f} s old')
            return None
        return pose.copy()

    def cube(self, max_estimate_age_s):
        """(centre in base_link now, centre in odom) of the latest cube estimate, moved by
        odometry since it arrived; Refused when there is none or it is too old."""
        with self._lock:
            estimate, odom = self._estimate, self._odom
        if estimate is None:
            raise Refused('refused: no cube pose estimate (nothing on /abp/aspect_observation '
                          'with a hypothesis)')
        in_odom, stamp = estimate
        age = self._now() - stamp
        if age > max_estimate_age_s:
            raise Refused(f'refused: the cube pose estimate is {age:.1f} s old '
                          f'(max_estimate_age {max_estimate_age_s:.1f} s)')
        base = point_odom_to_base(odom if odom is not None else np.zeros(3), in_odom)
        return base, in_odom.copy()


__all__ = ['RobotState', 'point_base_to_odom', 'point_odom_to_base']
