"""Test fixture process: a model-sampled world behind the real skill interfaces.

It stands in for the sim bridge + perception + skills *as a world*, not as a
mock of ROS: it serves the real abp/skills/{orbit,push,lift,flip} actions and
abp/skills/check_feasibility over DDS (abp_common.names), samples each action's
outcome from the true model's transition probabilities (the paper's simulation
protocol), and publishes abp/aspect_observation at 5 Hz with observations sampled from the
observation model of the current state. It lets the planner and belief nodes be
tested end to end before (and independently of) the rendered simulation.

Arguments: model_set seed true_model_index [fail_action] [infeasible_action]
"""

import sys
import time

import numpy as np
import rclpy
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node

from abp_belief import population
from abp_belief.cube import ACTIONS, ORBIT_STEPS, STATES_PER_MODEL, action_index
from abp_common import names, qos
from abp_msgs.action import Flip, Lift, Orbit, Push
from abp_msgs.msg import AspectHypothesis, AspectObservation
from abp_msgs.srv import CheckFeasibility

# Orbit goal angle (deg) -> the ATG action it is.
ORBIT_ACTIONS = {45.0 * steps: action for action, steps in ORBIT_STEPS.items()}
SKILL_TYPES = {'orbit': Orbit, 'push': Push, 'lift': Lift, 'flip': Flip}


class ModelWorld(Node):
    def __init__(self, model_set, true_model, fail_action='', infeasible_action=''):
        super().__init__('model_world')
        self.models = model_set
        self.rng = np.random.default_rng(1234)
        self.node = true_model * STATES_PER_MODEL + int(self.rng.integers(STATES_PER_MODEL))
        self.fail_action = fail_action
        self.infeasible_action = infeasible_action
        self.executed = []
        group = ReentrantCallbackGroup()
        self.pub = self.create_publisher(AspectObservation, names.ASPECT_OBSERVATION,
                                         qos.RELIABLE)
        self.create_timer(0.2, self.publish_observation, callback_group=group)
        for name, action_type in SKILL_TYPES.items():
            ActionServer(self, action_type, names.skill_action(name),
                         lambda handle, n=name: self.execute(n, handle),
                         cancel_callback=lambda _: CancelResponse.ACCEPT, callback_group=group)
        self.create_service(CheckFeasibility, names.CHECK_FEASIBILITY, self.feasibility,
                            callback_group=group)

    def publish_observation(self):
        z = self.models.observation.sample(self.models.node_aspect[self.node], self.rng)
        msg = AspectObservation()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = 'base_link'
        msg.hypotheses = [AspectHypothesis(aspect_type=z[0], slots=list(z[1:]), support=1.0,
                                           score=1.0)]
        msg.hypotheses[0].object_pose.pose.position.x = 0.4
        msg.hypotheses[0].object_pose.pose.orientation.w = 1.0
        self.pub.publish(msg)

    def feasibility(self, request, response):
        actions = list(request.actions) or list(ACTIONS)
        response.actions = actions
        response.feasible = [a != self.infeasible_action for a in actions]
        response.reasons = ['' if a != self.infeasible_action else 'IK fails (test world)'
                            for a in actions]
        return response

    def execute(self, skill, handle):
        goal = handle.request
        action = ORBIT_ACTIONS.get(goal.angle_deg) if skill == 'orbit' else skill.upper()
        result = SKILL_TYPES[skill].Result()
        time.sleep(0.1)  # the skill "moves"
        if handle.is_cancel_requested:
            handle.canceled()
            result.reason = 'cancelled'
            return result
        if action == self.fail_action:
            handle.abort()
            result.success = False
            result.reason = 'grasp slipped (test world)'
            self.executed.append((action, False))
            print(f'EXECUTED {action} failed', flush=True)
            return result
        nodes, probs = self.models.successors(action_index(action), np.array([self.node]))
        self.node = int(self.rng.choice(nodes[0], p=probs[0]))
        self.executed.append((action, True))
        print(f'EXECUTED {action} ok', flush=True)
        handle.succeed()
        result.success = True
        result.duration.nanosec = 100_000_000
        return result


def main():
    kind, seed, true_model = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    fail_action = sys.argv[4] if len(sys.argv) > 4 else ''
    infeasible = sys.argv[5] if len(sys.argv) > 5 else ''
    models = population.robot_set(seed=seed) if kind == 'robot' else \
        population.random_visual_subset(30, seed=seed)
    rclpy.init()
    node = ModelWorld(models, true_model, fail_action, infeasible)
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    print(f'READY true={models.names[true_model]}', flush=True)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
