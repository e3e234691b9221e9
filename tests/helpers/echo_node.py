"""Child process for the round-trip tests: echoes every abp_msgs message back.

Subscribes to /roundtrip/in/<Type> for each message type and republishes the
received message unchanged on /roundtrip/out/<Type>; serves both abp_msgs
services by reflecting the request; runs an Orbit action server that sends
feedback through the four phases and honours cancel. Prints READY when set up.
"""

import sys
import time

import rclpy
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node

import abp_msgs.msg
from abp_common import qos
from abp_msgs.action import Orbit
from abp_msgs.srv import CheckFeasibility, ResetBelief

PHASES = ('approach', 'contact', 'stroke', 'retreat')


def message_types():
    return {name: getattr(abp_msgs.msg, name) for name in dir(abp_msgs.msg)
            if not name.startswith('_') and hasattr(getattr(abp_msgs.msg, name), 'SLOT_TYPES')}


class EchoNode(Node):
    def __init__(self):
        super().__init__('roundtrip_echo')
        group = ReentrantCallbackGroup()
        self._keep = []
        for name, msg_type in message_types().items():
            publisher = self.create_publisher(msg_type, f'/roundtrip/out/{name}', qos.RELIABLE)
            self._keep.append(self.create_subscription(
                msg_type, f'/roundtrip/in/{name}', publisher.publish, qos.RELIABLE))
        self.create_service(CheckFeasibility, '/roundtrip/check_feasibility', self._feasibility)
        self.create_service(ResetBelief, '/roundtrip/reset_belief', self._reset)
        self._orbit = ActionServer(
            self, Orbit, '/roundtrip/orbit', self._execute_orbit,
            goal_callback=self._accept_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group)

    def _feasibility(self, request, response):
        response.actions = list(request.actions)
        response.feasible = [i % 2 == 0 for i in range(len(request.actions))]
        response.reasons = ['' if i % 2 == 0 else f'unreachable: {a}'
                            for i, a in enumerate(request.actions)]
        return response

    def _reset(self, request, response):
        response.success = True
        response.message = f'reset with {len(request.model_prior)} prior entries'
        return response

    def _accept_goal(self, goal):
        if goal.angle_deg not in (-90.0, -45.0, 45.0, 90.0, 180.0):
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _execute_orbit(self, goal_handle):
        started = time.monotonic()
        steps = 40  # 2 s of motion in 50 ms ticks
        result = Orbit.Result()
        for step in range(steps):
            if goal_handle.is_cancel_requested:
                goal_handle.canceled()
                result.success = False
                result.reason = f'cancelled at step {step}'
                return result
            feedback = Orbit.Feedback()
            feedback.phase = PHASES[step * len(PHASES) // steps]
            feedback.progress = (step + 1) / steps
            goal_handle.publish_feedback(feedback)
            time.sleep(0.05)
        goal_handle.succeed()
        result.success = True
        result.reason = f'orbited {goal_handle.request.angle_deg:.0f} deg'
        elapsed = time.monotonic() - started
        result.duration.sec = int(elapsed)
        result.duration.nanosec = int((elapsed % 1) * 1e9)
        return result


def main():
    rclpy.init()
    node = EchoNode()
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    print('READY', flush=True)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
