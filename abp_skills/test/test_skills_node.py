"""The skill servers over real DDS, driving the test fixture `fake_robot.py` (a stand-in for
the sim bridge that follows /cmd_vel and the trajectory topics and publishes /joint_states
and /odom): refusals, the feasibility service, cancel, one-skill-at-a-time across
processes, and complete ORBIT and LIFT runs."""

import math
import os
import threading
import time
import uuid
from pathlib import Path

import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')
try:  # The node tests need the built workspace (scripts/bootstrap.sh; source scripts/env.sh).
    from abp_msgs.action import Lift, Orbit, Push
    from abp_msgs.msg import AspectHypothesis, AspectObservation
    from abp_msgs.srv import CheckFeasibility
except ImportError:
    pytest.skip('abp_msgs is not built/sourced (scripts/bootstrap.sh; source scripts/env.sh)',
                allow_module_level=True)

from action_msgs.msg import GoalStatus  # noqa: E402
from geometry_msgs.msg import TwistStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from trajectory_msgs.msg import JointTrajectory  # noqa: E402
from unique_identifier_msgs.msg import UUID  # noqa: E402

from abp_common import qos  # noqa: E402
from abp_common.qos import RELIABLE  # noqa: E402
from abp_common.server_handshake import wait_until_answering  # noqa: E402
from abp_description.controllers import CONTROLLERS  # noqa: E402

FAKE_ROBOT = Path(__file__).with_name('fake_robot.py')
# Fast motions so that the tests stay short (the defaults are for the real robot).
FAST = {
    'joint_velocity_scale': 1.0, 'joint_acceleration': 8.0, 'joint_jerk': 60.0,
    'cartesian_velocity': 0.25, 'cartesian_acceleration': 1.5, 'cartesian_jerk': 15.0,
    'base_linear_velocity': 0.4, 'base_linear_acceleration': 1.0, 'base_linear_jerk': 6.0,
    'base_angular_velocity': 1.5, 'base_angular_acceleration': 4.0,
    'base_angular_jerk': 25.0,
}


def executable(name):
    return os.path.join(ament_index.get_package_prefix('abp_skills'), 'lib', 'abp_skills', name)


# Under load, DDS discovery can bring the servers their first /joint_states and /odom
# seconds after they are ready: a goal waits for them (an event) instead of being refused.
STATE_WAIT = {'state_wait_timeout': 30.0}
# As rclpy's /rosout publisher: reliable, transient local.
ROSOUT = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.TRANSIENT_LOCAL)


def start_server(ros_processes, tester, name, **params):
    """Start the skills node `name` and wait until it is active (its lifecycle state, asked
    over its endpoint_status service)."""
    values = {**FAST, **STATE_WAIT, **params}
    argv = [executable(name), '--ros-args']
    for key, value in values.items():
        argv += ['-p', f'{key}:={value}']
    proc = ros_processes.start(argv)
    tester.wait_active(name)
    return proc


def start_robot(ros_processes, *args):
    """The fake robot; the tests wait for its /odom (an event) before they use it."""
    return ros_processes.start_python(FAKE_ROBOT, *args)


def hold_or_size(msg):
    """'hold' for a one-point trajectory at time 0 with zero velocities (a stop, as
    Jazzy's controllers take it), else the number of points."""
    if len(msg.points) == 1:
        point = msg.points[0]
        if point.time_from_start.sec == 0 and point.time_from_start.nanosec == 0 \
                and not any(point.velocities):
            return 'hold'
    return len(msg.points)


class Harness:
    """The test's own node: a perception stand-in (publishes the cube estimate from the
    fake odometry) and recorders of the robot commands."""

    def __init__(self, context, call_service):
        self.call_service = call_service  # the root conftest's call_until_answered
        self.node = rclpy.create_node('skills_tester', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.cube_odom = None          # (x, y) of the cube in odom, or None: no estimate
        self.odom = None
        self.odom_count = 0
        self.odom_stamp = None
        self.cmd_vel = []              # (time, v, w)
        self.trajectories = {c: [] for c in CONTROLLERS}   # (time, number of points)
        self.lock = threading.Lock()
        self.obs_pub = self.node.create_publisher(AspectObservation, '/abp/aspect_observation',
                                                  RELIABLE)
        self.node.create_subscription(Odometry, '/odom', self._on_odom, RELIABLE)
        self.node.create_subscription(TwistStamped, '/cmd_vel', self._on_cmd, RELIABLE)
        for c in CONTROLLERS:
            self.node.create_subscription(
                JointTrajectory, f'/{c}/joint_trajectory',
                lambda msg, c=c: self.trajectories[c].append((time.monotonic(), hold_or_size(msg))),
                RELIABLE)
        self.node.create_timer(0.2, self._publish_estimate)
        self.logs = []                 # (node name, text) of every /rosout message
        self._log_read = {}            # node name -> how many of its lines were awaited
        self.node.create_subscription(Log, '/rosout',
                                      lambda m: self.logs.append((m.name, m.msg)), ROSOUT)

    def _on_odom(self, msg):
        p = msg.pose.pose
        self.odom = (p.position.x, p.position.y,
                     2 * math.atan2(p.orientation.z, p.orientation.w), msg.twist.twist)
        self.odom_count += 1
        self.odom_stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec

    def _on_cmd(self, msg):
        self.cmd_vel.append((time.monotonic(), msg.twist.linear.x, msg.twist.angular.z))

    def _publish_estimate(self):
        if self.cube_odom is None or self.odom is None:
            return
        x, y, yaw, _ = self.odom
        dx, dy = self.cube_odom[0] - x, self.cube_odom[1] - y
        hyp = AspectHypothesis(aspect_type=2, slots=[0, 1, -1], support=2.0, score=1.0)
        hyp.object_pose.pose.position.x = math.cos(yaw) * dx + math.sin(yaw) * dy
        hyp.object_pose.pose.position.y = -math.sin(yaw) * dx + math.cos(yaw) * dy
        hyp.object_pose.pose.position.z = 0.05
        msg = AspectObservation(hypotheses=[hyp])
        msg.header.frame_id = 'base_link'
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.obs_pub.publish(msg)

    def spin(self, predicate, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def wait_future(self, future, timeout=30.0):
        assert self.spin(future.done, timeout), 'no answer in time'
        return future.result()

    def feasibility(self, actions=()):
        """Ask the feasibility service. A new client's first request can be answered
        before the server's response writer has matched the client (DDS discovery is
        not symmetric): that answer is lost, so an unanswered request is sent again."""
        client = self.node.create_client(CheckFeasibility, '/abp/skills/check_feasibility')
        res = self.call_service(self.executor, client,
                                CheckFeasibility.Request(actions=list(actions)), 30.0,
                                attempt_s=3.0, ready_timeout=20.0)
        self.node.destroy_client(client)
        return {a: (ok, r) for a, ok, r in zip(res.actions, res.feasible, res.reasons)}

    def set_parameter(self, node, name, value, timeout=30.0):
        """Set a parameter of a node over its service (asked again when an answer is lost
        in discovery: setting it twice does no harm)."""
        client = self.node.create_client(SetParameters, f'{node}/set_parameters')
        assert self.spin(client.service_is_ready, 20), f'no {node}/set_parameters'
        request = SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()])
        deadline = time.monotonic() + timeout
        while True:
            future = client.call_async(request)
            if self.spin(future.done, 3.0):
                break
            client.remove_pending_request(future)
            assert time.monotonic() < deadline, f'{node}/set_parameters did not answer'
        self.node.destroy_client(client)
        assert all(r.successful for r in future.result().results), future.result()

    def wait_active(self, node, timeout=60.0):
        """Wait until `node` reports the lifecycle state active (abp_common.lifecycle's
        endpoint_status service: success once active)."""
        client = self.node.create_client(Trigger, f'/{node}/endpoint_status')
        deadline = time.monotonic() + timeout
        try:
            while True:
                answer = self.call_service(self.executor, client, Trigger.Request(),
                                           max(deadline - time.monotonic(), 1.0))
                if answer.success:
                    return
                assert time.monotonic() < deadline, f'{node} not active: {answer.message}'
                self.spin(lambda: False, 0.2)
        finally:
            self.node.destroy_client(client)

    def wait_logged(self, node, text, timeout):
        """Wait for a /rosout message of `node` containing `text`, after those already
        awaited (a ROS message: the node's own account of an event the graph does not
        otherwise show, such as a peer's claim it has taken in)."""
        def found():
            lines = [msg for name, msg in self.logs if name == node]
            start = self._log_read.get(node, 0)
            hit = next((i for i, msg in enumerate(lines[start:], start) if text in msg), None)
            if hit is not None:
                self._log_read[node] = hit + 1
            return hit is not None
        assert self.spin(found, timeout), \
            f'{node} did not log {text!r}: {[m for n, m in self.logs if n == node]}'

    def odom_after_now(self, timeout=20.0):
        """The odometry of a /odom message stamped after now (the fake robot stamps it
        on this machine's clock): what the robot did after, not a message still in the
        queue from before."""
        now = self.node.get_clock().now().nanoseconds * 1e-9
        assert self.spin(lambda: self.odom_stamp is not None and self.odom_stamp > now,
                         timeout), 'no new /odom'
        return self.odom

    def wait_final_feedback(self, feedback, timeout=10.0):
        """Feedback travels apart from the result: the last one (progress 1) can arrive
        after it (`send` reads the feedback topic, so it is not dropped)."""
        assert self.spin(lambda: feedback and feedback[-1].progress == pytest.approx(1.0),
                         timeout), 'no final feedback'

    def wait_until_feasibility(self, action, predicate, timeout=20.0):
        """Ask the feasibility service until `predicate((ok, reason))` holds for `action`:
        the server sees the estimate and states the tester publishes only after DDS
        delivered them, which can take a while on a loaded machine."""
        deadline = time.monotonic() + timeout
        answer = self.feasibility([action])[action]
        while not predicate(answer) and time.monotonic() < deadline:
            self.spin(lambda: False, 0.3)
            answer = self.feasibility([action])[action]
        return answer

    def send(self, action_type, name, goal, feedback=None):
        """Send a goal; its feedback goes into the list `feedback`. The feedback is read
        from the action's feedback topic, not through the client: rclpy's ActionClient
        drops feedback that arrives after the result, and the last feedback and the result
        travel on different DDS entities, so either can come first."""
        client = ActionClient(self.node, action_type, f'/abp/skills/{name}')
        assert wait_until_answering(client, self.spin, 20), f'no {name} server'
        goal_id = UUID(uuid=list(uuid.uuid4().bytes))
        if feedback is not None:
            def on_feedback(msg):
                if bytes(msg.goal_id.uuid) == bytes(goal_id.uuid):
                    feedback.append(msg.feedback)
            topic = f'/abp/skills/{name}/_action/feedback'
            sub = self.node.create_subscription(action_type.Impl.FeedbackMessage, topic,
                                                on_feedback, qos.reliable(100))
            assert self.spin(lambda: sub.get_publisher_count() > 0, 20), f'no {topic}'
        handle = self.wait_future(client.send_goal_async(goal, goal_uuid=goal_id))
        assert handle.accepted
        return client, handle

    def result(self, handle, timeout=60.0):
        return self.wait_future(handle.get_result_async(), timeout)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def tester(rclpy_context, call_service):
    t = Harness(rclpy_context, call_service)
    yield t
    t.close()


def test_refusals_and_the_feasibility_service(ros_processes, tester):
    start_robot(ros_processes)
    start_server(ros_processes, tester, 'skill_servers', max_estimate_age=1.5)
    assert tester.spin(lambda: tester.odom is not None, 20)

    # No estimate at all: every action infeasible, every skill refused.
    answer = tester.feasibility()
    assert list(answer) == ['ORBIT_P45', 'ORBIT_M45', 'ORBIT_P90', 'ORBIT_M90', 'ORBIT_180',
                            'PUSH', 'LIFT', 'FLIP']
    assert all(not ok and 'no cube pose estimate' in r for ok, r in answer.values())
    _, handle = tester.send(Orbit, 'orbit', Orbit.Goal(angle_deg=90.0))
    res = tester.result(handle)
    assert res.status == GoalStatus.STATUS_ABORTED
    assert not res.result.success and 'no cube pose estimate' in res.result.reason

    # Cube far away (1.3 m): the manual skills are out of reach; ORBIT may still go.
    tester.cube_odom = (1.3, 0.0)
    tester.wait_until_feasibility('PUSH', lambda a: 'out of reach' in a[1])
    answer = tester.feasibility()
    for action in ('PUSH', 'LIFT', 'FLIP'):
        assert not answer[action][0] and 'out of reach' in answer[action][1]
    assert answer['ORBIT_P90'] == (True, '')
    _, handle = tester.send(Push, 'push', Push.Goal(face='front'))
    res = tester.result(handle)
    assert res.status == GoalStatus.STATUS_ABORTED
    assert res.result.reason.startswith('refused:') and 'out of reach' in res.result.reason
    assert tester.trajectories['right_arm_controller'] == []   # nothing moved

    # Bad goals are refused with a reason.
    _, handle = tester.send(Push, 'push', Push.Goal(face='top'))
    assert 'only the front face' in tester.result(handle).result.reason
    _, handle = tester.send(Orbit, 'orbit', Orbit.Goal(angle_deg=30.0))
    assert 'not one of' in tester.result(handle).result.reason

    # Cube in front: everything is feasible.
    tester.cube_odom = (0.4, 0.0)
    tester.wait_until_feasibility('LIFT', lambda a: a[0])
    answer = tester.feasibility()
    assert all(ok for ok, _ in answer.values()), answer
    assert tester.feasibility(['LIFT']) == {'LIFT': (True, '')}

    # The estimate goes stale (perception stops): refused again.
    tester.cube_odom = None
    assert 's old' in tester.wait_until_feasibility('LIFT', lambda a: 's old' in a[1])[1]
    _, handle = tester.send(Lift, 'lift', Lift.Goal())
    res = tester.result(handle)
    assert not res.result.success and 's old' in res.result.reason


def test_cancel_stops_the_robot_and_a_second_skill_is_rejected(ros_processes, tester):
    # This robot never stops by itself (no /cmd_vel timeout): only the skill's own zero
    # command can stop the base after the cancel.
    start_robot(ros_processes, '--cmd-timeout', '1e9')
    # Separate processes: the one-skill-at-a-time rule goes through /abp/skills/active.
    start_server(ros_processes, tester, 'orbit_server')
    start_server(ros_processes, tester, 'lift_server')
    tester.cube_odom = (0.4, 0.0)
    assert tester.spin(lambda: tester.odom is not None, 20)
    assert tester.wait_until_feasibility('ORBIT_180', lambda a: a[0])[0]
    # The lift server has found the orbit server on the claims topic (discovery done):
    # the ORBIT's claim will reach it while the ORBIT runs.
    tester.wait_logged('lift_server', 'skills peer /orbit_server: idle', 60)

    feedback = []
    _, orbit = tester.send(Orbit, 'orbit', Orbit.Goal(angle_deg=180.0), feedback)
    if not tester.spin(lambda: any(f.phase == 'stroke' for f in feedback), 20):
        res = tester.result(orbit, 5)
        pytest.fail(f'the orbit never reached its arc: {res.status} {res.result.reason}')
    assert tester.spin(lambda: abs(tester.odom[3].linear.x) > 0.05, 5), 'base not moving'

    # A second skill while ORBIT runs (in another process) is rejected with a reason. The
    # claim travels on a topic: the LIFT goes once the lift server says it has the claim.
    tester.wait_logged('lift_server', 'skills peer /orbit_server: orbit running', 30)
    _, lift = tester.send(Lift, 'lift', Lift.Goal())
    res = tester.result(lift, 10)
    assert res.status == GoalStatus.STATUS_ABORTED
    assert res.result.reason.startswith('rejected: busy') and 'orbit' in res.result.reason
    assert orbit.status == GoalStatus.STATUS_EXECUTING

    # Cancel mid-motion: zero /cmd_vel and a one-point hold on every controller (Jazzy's
    # joint_trajectory_controller refuses a trajectory without points).
    # Each is waited for as an event (DDS delivers them when the loaded machine lets it);
    # what is checked is the order: no motion command after the stop.
    n_cmd = len(tester.cmd_vel)
    n_traj = {c: len(tester.trajectories[c]) for c in CONTROLLERS}
    tester.wait_future(orbit.cancel_goal_async(), 10)
    res = tester.result(orbit, 10)
    assert res.status == GoalStatus.STATUS_CANCELED
    assert not res.result.success and res.result.reason == 'canceled'
    assert res.result.duration.sec + res.result.duration.nanosec * 1e-9 > 1.0

    def stop_index():
        after = tester.cmd_vel[n_cmd:]
        return next((i for i, c in enumerate(after) if c[1:] == (0.0, 0.0)), None)
    assert tester.spin(lambda: stop_index() is not None, 10), 'no zero /cmd_vel after cancel'
    for controller in CONTROLLERS:
        assert tester.spin(lambda c=controller: 'hold' in [
            n for _, n in tester.trajectories[c][n_traj[c]:]], 10), f'no hold sent to {controller}'
    assert all(n != 0 for c in CONTROLLERS for _, n in tester.trajectories[c]), \
        'a trajectory without points was sent'

    def still(odom):
        return abs(odom[3].linear.x) < 1e-9 and abs(odom[3].angular.z) < 1e-9
    assert tester.spin(lambda: still(tester.odom), 10), 'the base did not stop'
    # Stopped for good: the next 25 odometry messages (0.5 s of the robot's 50 Hz) show a
    # base at rest where it stopped, and no motion command came after the zero one.
    stopped, count = tester.odom[:2], tester.odom_count
    assert tester.spin(lambda: tester.odom_count >= count + 25, 20), 'odometry stopped'
    assert still(tester.odom) and math.dist(stopped, tester.odom[:2]) < 1e-6
    after = tester.cmd_vel[n_cmd:][stop_index():]
    assert all(c[1:] == (0.0, 0.0) for c in after), f'motion commands after the stop: {after}'

    # The claim was released: LIFT now runs (and is cancelled in its approach).
    tester.wait_logged('lift_server', 'skills peer /orbit_server: idle', 30)
    feedback = []
    _, lift = tester.send(Lift, 'lift', Lift.Goal(), feedback)
    assert tester.spin(lambda: any(f.phase == 'approach' and f.progress > 0.05
                                   for f in feedback), 20)
    tester.wait_future(lift.cancel_goal_async(), 10)
    assert tester.result(lift, 10).status == GoalStatus.STATUS_CANCELED


def test_orbit_and_lift_run_to_completion(ros_processes, tester):
    start_robot(ros_processes)
    start_server(ros_processes, tester, 'skill_servers')
    tester.cube_odom = (0.4, 0.0)
    assert tester.spin(lambda: tester.odom is not None, 20)
    assert tester.wait_until_feasibility('ORBIT_M90', lambda a: a[0])[0]

    feedback = []
    _, orbit = tester.send(Orbit, 'orbit', Orbit.Goal(angle_deg=-90.0), feedback)
    res = tester.result(orbit, 60)
    assert res.status == GoalStatus.STATUS_SUCCEEDED, res.result.reason
    assert res.result.success and res.result.reason == ''
    x, y, yaw, _ = tester.odom_after_now()
    # ORBIT(-90): the cube's relative yaw changes by -90 deg, i.e. the robot went +90 deg
    # (counter-clockwise) around it, and faces it again at the same distance.
    bearing = math.degrees(math.atan2(y - 0.0, x - 0.4))
    assert abs(((bearing - (-90.0)) + 180) % 360 - 180) < 3.0
    assert math.dist((x, y), (0.4, 0.0)) == pytest.approx(0.4, abs=0.03)
    to_cube = math.atan2(0.0 - y, 0.4 - x)
    assert abs((to_cube - yaw + math.pi) % (2 * math.pi) - math.pi) < math.radians(3)
    tester.wait_final_feedback(feedback)
    assert [f.phase for f in feedback][0] == 'approach' and feedback[-1].phase == 'stroke'
    progress = [f.progress for f in feedback]
    assert progress == sorted(progress) and progress[-1] == pytest.approx(1.0)

    feedback = []
    _, lift = tester.send(Lift, 'lift', Lift.Goal(), feedback)
    res = tester.result(lift, 60)
    assert res.status == GoalStatus.STATUS_SUCCEEDED, res.result.reason
    tester.wait_final_feedback(feedback)
    phases = []
    for f in feedback:
        if not phases or phases[-1] != f.phase:
            phases.append(f.phase)
    assert phases == ['approach', 'contact', 'stroke', 'retreat']
    assert res.result.duration.sec >= 2


def test_an_aborted_manual_skill_brings_the_arms_home(ros_processes, tester):
    # A skill timeout aborts the LIFT with the arms out; the server then brings them home
    # (phase 'recover', on its own time limit) so that they neither hold nor hide the cube.
    # The robot blocks the arms halfway through their first motion, and the timeout is
    # shortened only once they are blocked there: the abort finds the arms out whatever
    # the load (a timeout set at start could fall before they left home).
    start_robot(ros_processes, '--block-arms')
    # Long enough that the blocked arms are not given up on before the timeout is set.
    start_server(ros_processes, tester, 'skill_servers', settle_timeout=60.0)
    tester.cube_odom = (0.4, 0.0)
    assert tester.spin(lambda: tester.odom is not None, 20)
    assert tester.wait_until_feasibility('LIFT', lambda a: a[0])[0]
    feedback = []
    _, lift = tester.send(Lift, 'lift', Lift.Goal(), feedback)
    tester.wait_logged('fake_robot', 'arms blocked', 60)
    tester.set_parameter('/skill_servers', 'timeout', 1.0)
    res = tester.result(lift, 60)
    assert res.status == GoalStatus.STATUS_ABORTED, res.result.reason
    assert res.result.reason.startswith('timeout') and res.result.reason.endswith(
        '; arms back home'), res.result.reason
    assert tester.spin(lambda: any(f.phase == 'recover' for f in feedback), 10), \
        'no recover phase'


@pytest.mark.parametrize('override, expected', [
    ('push_hand:=middle', 'push_hand'),
    ('timeout:=-3.0', 'timeout'),
    ('orbit_min_radius:=2.0', 'orbit_min_radius'),
])
def test_bad_parameters_are_refused_clearly(override, expected, main_in_process):
    """The push_server executable's main() in this process (the exit code of a process
    start-up is checked once, in test_sim_bridge_node.py)."""
    from abp_skills.skills_node import push_main
    code, stderr = main_in_process(push_main, '-p', override)
    assert code == 2, stderr
    assert 'configuration error' in stderr and expected in stderr
    assert 'Traceback' not in stderr


def test_a_base_command_of_the_other_type_is_refused_with_both_types_named(ros_processes,
                                                                          tester):
    # The robot takes TwistStamped (Jazzy's diff_drive_controller); this server is set
    # to publish Twist on the same topic: DDS would carry nothing and say nothing.
    start_robot(ros_processes)
    start_server(ros_processes, tester, 'orbit_server', base_command_type='twist')
    tester.cube_odom = (0.4, 0.0)
    assert tester.spin(lambda: tester.odom is not None, 20)
    assert tester.wait_until_feasibility('ORBIT_P90', lambda a: a[0])[0]
    _, orbit = tester.send(Orbit, 'orbit', Orbit.Goal(angle_deg=90.0))
    res = tester.result(orbit, 30)
    assert res.status == GoalStatus.STATUS_ABORTED
    reason = res.result.reason
    assert 'geometry_msgs/msg/Twist' in reason and 'TwistStamped' in reason \
        and 'base_command_type' in reason, reason
