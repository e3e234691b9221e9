"""`respawn_probe`: how often a SIGKILLed, respawned managed node is not brought back.

    python -m abp_bench.respawn_probe [--node aspect_matcher] [--kills 20] [--deadline 60]
                                      [--respawn-delay 1.0] [--json FILE]

A lifecycle manager (`node_names:=[NODE]`) and the node (`autostart:=false`) run on a
domain of their own (localhost discovery). Each round: wait for the manager's latched
`graph_ready` to be true, SIGKILL the node, start a new process after `--respawn-delay`
s (start_graph.sh's supervisor waits 1 s), and time how long the manager takes to say
the graph is ready again. A round not back within `--deadline` s is a failure: the
probe then records whether the new process answers a client of its own (so the fault is
the manager's, not the node's), and the node's and the manager's Fast DDS shared-memory
ports (/dev/shm/fastrtps_port*, held open by the process) and UDP ports, and kills the
node again (the next round starts from a fresh process). Stuck rounds name the cause
(docs/RECOVERY.md). Transport choices come from the caller's environment (e.g.
FASTDDS_BUILTIN_TRANSPORTS=UDPv4), inherited by both processes.
"""

import argparse
import json
import os
import pathlib
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import rclpy
from ament_index_python.packages import get_package_prefix
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from abp_common import names, qos
from abp_common.shm_ports import SHM_DIR, freeze_listeners_between_messages
from abp_msgs.msg import TagDetectionArray

from .graph_benchmark import terminate_with_parent
from .soak import GRAPH_NODES

GRAPH_READY = '/lifecycle_manager/graph_ready'


def executable(package, name):
    return os.path.join(get_package_prefix(package), 'lib', package, name)


def fd_targets(pid):
    """What process `pid`'s open file descriptors point to, or None if it cannot be read."""
    targets = []
    try:
        for fd in pathlib.Path(f'/proc/{pid}/fd').iterdir():
            try:
                targets.append(os.readlink(fd))
            except OSError:
                continue
    except OSError:
        return None
    return targets


def shm_ports(pid):
    """The Fast DDS shared-memory files process `pid` has open (its own port, the ports it
    sends to, its segment)."""
    found = {t[len('/dev/shm/'):] for t in fd_targets(pid) or () if t.startswith('/dev/shm/')}
    try:
        for line in pathlib.Path(f'/proc/{pid}/maps').read_text().splitlines():
            if '/dev/shm/' in line:
                found.add(line.split('/dev/shm/', 1)[1])
    except OSError:
        pass
    return sorted(found)


def udp_ports(pid):
    """Local UDP ports of process `pid` (its sockets' inodes, looked up in /proc/net/udp)."""
    targets = fd_targets(pid)
    if targets is None:
        return []
    inodes = {t[8:-1] for t in targets if t.startswith('socket:[')}
    ports = set()
    for table in ('/proc/net/udp', '/proc/net/udp6'):
        try:
            lines = pathlib.Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if fields[9] in inodes:
                ports.add(int(fields[1].rsplit(':', 1)[1], 16))
    return sorted(ports)


ASK_FROM_A_NEW_PROCESS = """
import json, sys, rclpy
from std_srvs.srv import Trigger
rclpy.init()
node = rclpy.create_node('respawn_probe_fresh')
client = node.create_client(Trigger, sys.argv[1])
if not client.wait_for_service(timeout_sec=10.0):
    print('service not listed'); sys.exit(0)
future = client.call_async(Trigger.Request())
rclpy.spin_until_future_complete(node, future, timeout_sec=10.0)
print(json.loads(future.result().message)['state'] if future.done() else 'no answer')
"""


class Probe:
    def __init__(self, args, log_dir):
        self.args = args
        self.log_dir = log_dir
        package, name = GRAPH_NODES[args.node]
        self.node_command = [executable(package, name), '--ros-args',
                             '-p', 'autostart:=false']
        self.manager_command = [executable('abp_bringup', 'lifecycle_manager'), '--ros-args',
                                '-p', f'node_names:=[{args.node}]']
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.ros = rclpy.create_node('respawn_probe', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.ros)
        self.ready = []            # (monotonic time, bool)
        self.changed = threading.Condition()
        self.ros.create_subscription(Bool, GRAPH_READY, self._on_ready, qos.LATCHED)
        self.spinner = threading.Thread(target=self._spin, daemon=True)
        self.spinner.start()
        if args.traffic > 0 and args.node == 'aspect_matcher':
            # Keep the node's shared-memory listener busy, as the detector does in the
            # graph (the node drops these: no tag, and no joint state for the stamp).
            self.detections = self.ros.create_publisher(
                TagDetectionArray, names.TAG_DETECTIONS, qos.RELIABLE)
            self.ros.create_timer(1.0 / args.traffic, self._publish_detections)
        self.starts = 0
        self.manager = self._start(self.manager_command, 'lifecycle_manager.log')
        self.node = self._start_node()

    def _spin(self):
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.2)
            except Exception:  # noqa: BLE001 -- shutting down
                return

    def _publish_detections(self):
        msg = TagDetectionArray()
        msg.header.frame_id = 'camera'
        msg.header.stamp = self.ros.get_clock().now().to_msg()
        self.detections.publish(msg)

    def _on_ready(self, msg):
        with self.changed:
            self.ready.append((time.monotonic(), msg.data))
            self.changed.notify_all()

    def _start(self, command, log_name):
        log = open(self.log_dir / log_name, 'a')  # noqa: SIM115 -- the child writes it
        return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT,
                                preexec_fn=terminate_with_parent)

    def _start_node(self):
        self.starts += 1
        return self._start(self.node_command, f'{self.args.node}.log')

    def wait_ready(self, after, timeout):
        """Monotonic time of the first graph_ready true received after `after`, or None.
        (The manager publishes only changes, so a true after a kill is the way back.)"""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                for stamp, value in self.ready:
                    if stamp >= after and value:
                        return stamp
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self.changed.wait(left)

    def answers_own_client(self, timeout=10.0):
        """Whether the node answers endpoint_status to a client created now."""
        client = self.ros.create_client(Trigger, f'/{self.args.node}/endpoint_status')
        try:
            if not client.wait_for_service(timeout_sec=timeout):
                return 'service not listed'
            future = client.call_async(Trigger.Request())
            done = threading.Event()
            future.add_done_callback(lambda _: done.set())
            if not done.wait(timeout):
                client.remove_pending_request(future)
                return 'no answer'
            return json.loads(future.result().message)['state']
        finally:
            self.ros.destroy_client(client)

    def answers_from_a_new_process(self):
        """Whether the node answers endpoint_status to a process started now (a DDS
        participant that never sent to the killed node)."""
        try:
            done = subprocess.run(
                [sys.executable, '-c', ASK_FROM_A_NEW_PROCESS,
                 f'/{self.args.node}/endpoint_status'],
                capture_output=True, text=True, timeout=60)
        except subprocess.TimeoutExpired:
            return 'timed out'
        return (done.stdout.strip() or done.stderr.strip()[-200:])

    def round(self, index):
        old = self.node
        old_shm = shm_ports(old.pid)
        old_udp = udp_ports(old.pid)
        if self.args.traffic > 0:
            time.sleep(random.uniform(0.0, 1.0))   # a random moment of the traffic
        killed_at = time.monotonic()
        old.send_signal(signal.SIGKILL)
        old.wait()
        injected = {}
        if self.args.inject_idle_listener:
            for name in old_shm:
                if name.endswith('_el') and name.startswith('fastrtps_port'):
                    port = name[:-len('_el')]
                    injected[port] = freeze_listeners_between_messages(SHM_DIR / port)
        time.sleep(self.args.respawn_delay)
        self.node = self._start_node()
        back = self.wait_ready(killed_at, self.args.deadline)
        result = {'round': index, 'back_s': None if back is None else round(back - killed_at, 2),
                  'killed_udp': old_udp, 'new_udp': udp_ports(self.node.pid)}
        if injected:
            result['injected'] = injected
        if back is None:
            result.update({
                'killed_shm': old_shm, 'new_shm': shm_ports(self.node.pid),
                'manager_shm': shm_ports(self.manager.pid),
                'answers_the_probe': self.answers_own_client(),
                'answers_a_new_process': self.answers_from_a_new_process(),
                'manager_log_tail': (self.log_dir / 'lifecycle_manager.log').read_text()
                .splitlines()[-6:]})
        print(json.dumps(result), flush=True)
        return result

    def stop(self):
        for proc in (self.node, self.manager):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in (self.node, self.manager):
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self.executor.shutdown()
        self.ros.destroy_node()
        rclpy.try_shutdown(context=self.context)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--node', default='aspect_matcher', choices=sorted(GRAPH_NODES))
    parser.add_argument('--kills', type=int, default=20)
    parser.add_argument('--deadline', type=float, default=60.0,
                        help='seconds for the manager to bring the respawned node back')
    parser.add_argument('--respawn-delay', type=float, default=1.0)
    parser.add_argument('--traffic', type=float, default=0.0,
                        help='publish empty tag detections to the aspect_matcher at this '
                             'rate (Hz), and kill at a random moment of it')
    parser.add_argument('--inject-idle-listener', action='store_true',
                        help="after each kill, mark the dead node's shared-memory listeners "
                             'as killed between two messages (see '
                             'freeze_listeners_between_messages)')
    parser.add_argument('--json', type=pathlib.Path)
    args = parser.parse_args(argv)
    if args.kills < 1 or args.deadline <= 0 or args.respawn_delay < 0:
        parser.error('--kills must be >= 1, --deadline > 0, --respawn-delay >= 0')
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randrange(1, 101)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)
    log_dir = pathlib.Path(tempfile.mkdtemp(prefix='abp-respawn-'))
    print(f'domain {os.environ["ROS_DOMAIN_ID"]}, transports '
          f'{os.environ.get("FASTDDS_BUILTIN_TRANSPORTS", "default")}, logs in {log_dir}',
          flush=True)
    probe = Probe(args, log_dir)
    results = []
    try:
        first = probe.wait_ready(0.0, max(args.deadline, 120.0))
        if first is None:
            print('the graph never became ready the first time', file=sys.stderr)
            return 1
        for index in range(args.kills):
            result = probe.round(index)
            results.append(result)
            if result['back_s'] is None:
                # Start the next round from a process the manager has brought up.
                probe.node.send_signal(signal.SIGKILL)
                probe.node.wait()
                probe.node = probe._start_node()
                if probe.wait_ready(time.monotonic(), max(args.deadline, 120.0)) \
                        is None:
                    print('not back after a second respawn either: stopping', flush=True)
                    break
    finally:
        probe.stop()
    back = [r['back_s'] for r in results if r['back_s'] is not None]
    summary = {'node': args.node, 'rounds': len(results),
               'stuck': len(results) - len(back), 'deadline_s': args.deadline,
               'back_s_median': statistics.median(back) if back else None,
               'back_s_max': max(back) if back else None,
               'traffic_hz': args.traffic,
               'inject_idle_listener': args.inject_idle_listener,
               'transports': os.environ.get('FASTDDS_BUILTIN_TRANSPORTS', 'default'),
               'logs': str(log_dir)}
    print(json.dumps(summary), flush=True)
    if args.json:
        args.json.write_text(json.dumps({'summary': summary, 'rounds': results}, indent=1))
    return 0 if summary['stuck'] == 0 else 1


if __name__ == '__main__':
    sys.exit(main())
