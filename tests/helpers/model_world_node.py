"""Test fixture process: a model-sampled world behind the real skill interfaces.

It stands in for the sim bridge + perception + skills *as a world*, not as a
mock of ROS: it serves the real abp/skills/{orbit,push,lift,flip} actions and
abp/skills/check_feasibility over DDS (abp_common.names), samples each action's
outcome from the true model's transition probabilities (the paper's simulation
protocol), and publishes abp/aspect_observation at 5 Hz with observations sampled from the
observation model of the current state. It lets the planner and belief nodes be
tested end to end before (and independently of) the rendered simulation.

Arguments: model_set seed true_model_index [fail_action] [infeasible_action] [noise_seed]
(noise_seed: seeds the outcome and observation noise; default: the fixed streams of the
tests.)

Several objects (issue 37): true_model_index as a comma-separated list of model indices
(e.g. 0,11,20) places one cube of each, tracks cube1, cube2, ... (each with its own
seeded noise stream), all in view: every tick publishes one observation per cube with its
track_id and cube_pose. A skill's outcome is applied to the cube the planner says it acted
on, the track_id of its abp/executed_action; until that message arrives after a skill the
world publishes nothing (the robot is moving: no frame may show the cube before the
action under a stamp after it).
"""

import sys
import threading
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
from abp_msgs.msg import AspectHypothesis, AspectObservation, ExecutedAction
from abp_msgs.srv import CheckFeasibility

# A skill whose executed action never comes: resume observing after this long.
EXECUTED_WAIT_S = 30.0
# Orbit goal angle (deg) -> the ATG action it is.
ORBIT_ACTIONS = {45.0 * steps: action for action, steps in ORBIT_STEPS.items()}
SKILL_TYPES = {'orbit': Orbit, 'push': Push, 'lift': Lift, 'flip': Flip}


class ModelWorld(Node):
    def __init__(self, model_set, true_model, fail_action='', infeasible_action='',
                 noise_seed=None):
        super().__init__('model_world')
        self.models = model_set
        self.rng = np.random.default_rng(1234 if noise_seed is None else [1234, noise_seed])
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
        self.pub.publish(self.observation(z, self.get_clock().now().to_msg()))

    @staticmethod
    def observation(z, stamp, track_id='', y=0.0):
        msg = AspectObservation(track_id=track_id)
        msg.header.stamp = stamp
        msg.header.frame_id = 'base_link'
        msg.hypotheses = [AspectHypothesis(aspect_type=z[0], slots=list(z[1:]), support=1.0,
                                           score=1.0)]
        msg.hypotheses[0].object_pose.pose.position.x = 0.4
        msg.hypotheses[0].object_pose.pose.position.y = y
        msg.hypotheses[0].object_pose.pose.orientation.w = 1.0
        if track_id:
            msg.cube_pose = msg.hypotheses[0].object_pose.pose
        return msg

    def outcome_deferred(self, action):
        """False: the one cube's outcome is sampled at once, in the skill."""
        return False

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
        if not self.outcome_deferred(action):
            nodes, probs = self.models.successors(action_index(action), np.array([self.node]))
            self.node = int(self.rng.choice(nodes[0], p=probs[0]))
        self.executed.append((action, True))
        print(f'EXECUTED {action} ok', flush=True)
        handle.succeed()
        result.success = True
        result.duration.nanosec = 100_000_000
        return result


class SceneWorld(ModelWorld):
    """K cubes, one model each (module doc); the skill outcome goes to the cube named by
    the planner's executed action."""

    def __init__(self, model_set, true_models, seed, fail_action='', infeasible_action='',
                 noise_seed=None):
        super().__init__(model_set, true_models[0], fail_action, infeasible_action)
        self.tracks = [f'cube{k + 1}' for k in range(len(true_models))]
        streams = [seed] if noise_seed is None else [seed, noise_seed]
        self.rngs = [np.random.default_rng([*streams, k]) for k in range(len(true_models))]
        self.nodes = {track: model * STATES_PER_MODEL + int(rng.integers(STATES_PER_MODEL))
                      for track, model, rng in zip(self.tracks, true_models, self.rngs)}
        self.lock = threading.Lock()
        self.pending = None   # (action, monotonic time) of a skill whose cube is not known yet
        self.create_subscription(ExecutedAction, names.EXECUTED_ACTION, self.on_executed,
                                 qos.RELIABLE)

    def publish_observation(self):
        with self.lock:
            if self.pending is not None and \
                    time.monotonic() - self.pending[1] < EXECUTED_WAIT_S:
                return
            self.pending = None
            stamp = self.get_clock().now().to_msg()
            frames = [self.observation(
                self.models.observation.sample(self.models.node_aspect[self.nodes[track]],
                                               rng), stamp, track, y=0.3 * k)
                for k, (track, rng) in enumerate(zip(self.tracks, self.rngs))]
        for msg in frames:
            self.pub.publish(msg)

    def outcome_deferred(self, action):
        """The skill ran: hold the observations until the planner says on which cube."""
        with self.lock:
            self.pending = (action, time.monotonic())
        return True

    def on_executed(self, msg):
        with self.lock:
            if self.pending is None or self.pending[0] != msg.action:
                return
            self.pending = None
            if not msg.success:
                return
            if msg.track_id not in self.nodes:
                print(f'EXECUTED {msg.action} on unknown track {msg.track_id!r}', flush=True)
                return
            k = self.tracks.index(msg.track_id)
            nodes, probs = self.models.successors(action_index(msg.action),
                                                  np.array([self.nodes[msg.track_id]]))
            self.nodes[msg.track_id] = int(self.rngs[k].choice(nodes[0], p=probs[0]))
        print(f'EXECUTED {msg.action} on {msg.track_id}', flush=True)


def main():
    kind, seed, true_models = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    fail_action = sys.argv[4] if len(sys.argv) > 4 else ''
    infeasible = sys.argv[5] if len(sys.argv) > 5 else ''
    noise_seed = int(sys.argv[6]) if len(sys.argv) > 6 else None
    models = population.robot_set(seed=seed) if kind == 'robot' else \
        population.random_visual_subset(30, seed=seed)
    rclpy.init()
    if ',' in true_models:
        indices = [int(m) for m in true_models.split(',')]
        node = SceneWorld(models, indices, seed, fail_action, infeasible, noise_seed)
        truth = ' '.join(f'{t}={models.names[m]}' for t, m in zip(node.tracks, indices))
    else:
        node = ModelWorld(models, int(true_models), fail_action, infeasible, noise_seed)
        truth = models.names[int(true_models)]
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    print(f'READY true={truth}', flush=True)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
