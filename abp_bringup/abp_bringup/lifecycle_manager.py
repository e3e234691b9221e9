"""The graph's lifecycle manager: `ros2 run abp_bringup lifecycle_manager`.

Like nav2_lifecycle_manager: it brings the managed nodes of `node_names` up in that order
(configure, then activate, through each node's `<node>/change_state` service), watches
them every `check_period` s, and declares the graph ready when every node is active and
every topic edge between two managed nodes is matched on both ends (each node's
`<node>/endpoint_status`, abp_common.lifecycle; the rule is
abp_common.lifecycle_report.unmatched). Then it logs `graph ready` once and publishes
true on `~/graph_ready` (std_msgs/Bool, latched); `~/is_active` (std_srvs/Trigger)
answers the same. When the graph stops being ready (a node died, was deactivated) it
logs `graph not ready: <why>` and publishes false.

Each node instance (process) is brought up once: a node that refuses a transition is
logged (`bringup failed: <node> refused to configure ...`; the node's own log says why)
and not asked again, and a node deactivated or cleaned up by someone else stays so. A
respawned node is a new instance: the manager sees it unconfigured and brings it back
to active. A transition request or reply that DDS drops (a respawned node has not
discovered the manager yet) is told from a slow transition by the node's own report and
sent again. (A respawned node that no process reached at all, run 65: Fast DDS
shared-memory ports after a SIGKILL, retired by every node at start-up; docs/RECOVERY.md.)

Independent nodes come up together: every node that answers is configured at once (one
thread each, so loading model sets, compiling the MuJoCo world and opening the camera
overlap), and activated as soon as it is configured, except that until the graph was
first ready the nodes of `activate_first` (the sim bridge: the /clock and sensors the
others run on) are activated before any other node is. With `autostart:=false` the
manager only watches until `~/startup` (std_srvs/Trigger) is called, which also brings
every node that is not active up again.
"""

import json
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from abp_common import qos
from abp_common.graph_nodes import GRAPH_NODE_NAMES
from abp_common.lifecycle_report import next_transition, not_active, unmatched
from abp_common.node_runner import run_node
from abp_common.param_spec import BOOL, DOUBLE, STRING_ARRAY, ParamSpec
from abp_common.parameters import declare_all
from abp_common.tolerant_subscriptions import TolerantNode

# In dependency order (abp_common.graph_nodes).
GRAPH_NODES = GRAPH_NODE_NAMES
READY_LINE = 'graph ready'
BRINGUP_CHECK_PERIOD_S = 0.1
# How long a watch round waits for the answers to its requests; later answers are taken
# in a later round (each round asks again, so a respawned node is seen at once).
ROUND_WAIT_S = 1.0
MAX_REQUESTS_IN_FLIGHT = 20   # per node: a silent node is not asked without bound
TRANSITIONS = {'configure': Transition.TRANSITION_CONFIGURE,
               'activate': Transition.TRANSITION_ACTIVATE}
STATE_AFTER = {'configure': 'inactive', 'activate': 'active'}


def transition_request(transition):
    """The ChangeState request for `transition`, by label as well as id: a node resolves
    a label from its current state and refuses (success false) one it cannot take there,
    where an id alone that is not valid in its state (a request sent again after the
    first did its work) makes rclpy's LifecycleNode raise in its executor and die."""
    return ChangeState.Request(transition=Transition(id=TRANSITIONS[transition],
                                                     label=transition))
MANAGER_SPECS = [
    ParamSpec('node_names', STRING_ARRAY, list(GRAPH_NODES),
              "The managed nodes (names relative to the manager's namespace); they are "
              'configured and activated together.', read_only=True),
    ParamSpec('activate_first', STRING_ARRAY, ['sim_bridge'],
              'Managed nodes activated before the others at the first bring-up (the source '
              'of /clock and the sensors); names not in node_names are ignored.',
              read_only=True),
    ParamSpec('autostart', BOOL, True,
              'Bring the nodes up at once (true), or only watch until ~/startup is called.',
              read_only=True),
    ParamSpec('check_period', DOUBLE, 0.5,
              'Seconds between two checks of the nodes (at most 0.1 s until the graph '
              'was first ready).',
              (0.05, 60.0)),
    ParamSpec('service_timeout', DOUBLE, 5.0,
              "Seconds to wait for a node's endpoint_status answer, and for the answer to a "
              'transition before asking the node whether the request was lost.', (0.1, 600.0)),
    ParamSpec('transition_timeout', DOUBLE, 300.0,
              'Seconds to wait for a configure or activate to finish (loading a large '
              'model set takes a while); a request the node never received is sent again.',
              (1.0, 3600.0)),
    ParamSpec('log_period', DOUBLE, 10.0,
              'Seconds between two log lines saying what the graph is waiting for.',
              (0.5, 3600.0)),
]


class LifecycleManager(TolerantNode):
    def __init__(self):
        super().__init__('lifecycle_manager')
        self.values = declare_all(self, MANAGER_SPECS)
        self.node_names = list(self.values['node_names'])
        if not self.node_names:
            raise ValueError('parameter node_names: no node to manage')
        self._status = {n: self.create_client(Trigger, f'{n}/endpoint_status')
                        for n in self.node_names}
        self._change = {n: self.create_client(ChangeState, f'{n}/change_state')
                        for n in self.node_names}
        self._first = [n for n in self.values['activate_first'] if n in self.node_names]
        self._settled = {}
        self._in_flight = {n: [] for n in self.node_names}  # [(sent, future, event)]
        self._answers = {}            # node -> (sent, report) of its newest request answered
        self._last_todo = []          # node -> the instance brought up (or refused) last
        self._ready = None
        self._was_ready = False
        self._why = 'not checked yet'
        self._last_log = 0.0
        self._managing = threading.Event()
        if self.values['autostart']:
            self._managing.set()
        self._ready_pub = self.create_publisher(Bool, '~/graph_ready', qos.LATCHED)
        self._ready_pub.publish(Bool(data=False))
        self.create_service(Trigger, '~/is_active', self._on_is_active)
        self.create_service(Trigger, '~/startup', self._on_startup)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name='manager', daemon=True)
        self._thread.start()
        self.get_logger().info(f'managing {", ".join(self.node_names)}'
                               f'{"" if self.values["autostart"] else " (waiting for startup)"}')

    # -- services ------------------------------------------------------------------------
    def _on_is_active(self, request, response):
        response.success = bool(self._ready)
        response.message = READY_LINE if self._ready else f'not ready: {self._why}'
        return response

    def _on_startup(self, request, response):
        self._settled.clear()
        self._managing.set()
        response.success = True
        response.message = f'bringing up {", ".join(self.node_names)}'
        return response

    def stop(self):
        self._stop.set()
        self._thread.join(timeout=5.0)

    # -- the watch loop (its own thread; the executor takes the answers) -----------------
    def _loop(self):
        while not self._stop.is_set() and self.context.ok():
            try:
                self._check()
            except Exception as error:  # noqa: BLE001 -- keep watching
                if not self.context.ok():
                    return
                self.get_logger().error(f'check failed: {type(error).__name__}: {error}')
            # Until the graph was first ready, look again soon: a node that has just
            # appeared, or an edge just matched, should not wait a whole check_period.
            self._stop.wait(self.values['check_period'] if self._was_ready else
                            min(self.values['check_period'], BRINGUP_CHECK_PERIOD_S))

    def _check(self):
        reports = self._watch_round()
        if self._ready and not_active(reports, self.node_names):
            # Said before bringing a respawned node back: the graph was not ready while it
            # was gone, however fast it is back.
            self._update_ready(reports)
        if self._managing.is_set():
            brought_up = self._bring_up_all(reports)
            # Newer than any answer still in flight, which a later round must not take.
            now = time.monotonic()
            self._answers.update((name, (now, report)) for name, report in brought_up.items())
            reports.update(brought_up)
        self._update_ready(reports)

    def _bring_up_all(self, reports):
        """Bring every answering node up at once, one thread each; returns {node: new
        report} of those asked. Before the first `graph ready` the others are activated
        only once every node of activate_first is active."""
        todo = [n for n in self.node_names if n in reports and next_transition(
            reports[n]['state'], reports[n]['instance'], self._settled.get(n)) is not None]
        if not todo:
            return {}
        if todo != self._last_todo:
            self.get_logger().info(f'bringing up {", ".join(todo)} together')
            self._last_todo = todo
        first_up = threading.Event()
        gated = not self._was_ready and any(
            reports.get(n, {}).get('state') != 'active' for n in self._first)
        if not gated:
            first_up.set()
        first_reports = {n: reports.get(n) for n in self._first}
        first_left = [n for n in self._first if n in todo]
        lock = threading.Lock()

        def first_done(name, report):
            with lock:
                first_reports[name] = report
                first_left.remove(name)
                if not first_left:
                    first_up.set()   # every first node is through: active or not

        def bring_up(name):
            report = reports[name]
            try:
                if name in self._first or not gated:
                    report = self._bring_up(name, report) or report
                    return report
                report = self._bring_up(name, report, until='inactive') or report
                first_up.wait()
                if all(r is not None and r['state'] == 'active'
                       for r in first_reports.values()):
                    report = self._bring_up(name, report) or report
                return report
            finally:
                if name in first_left:
                    first_done(name, report)

        if not first_left:
            first_up.set()   # no first node to wait for: the others are only configured
        with ThreadPoolExecutor(max_workers=len(todo),
                                thread_name_prefix='bringup') as pool:
            return dict(zip(todo, pool.map(bring_up, todo)))

    def _bring_up(self, name, report, until='active'):
        """Configure and/or activate one node instance, up to the state `until`; returns
        its new report."""
        instance = report['instance']
        while True:
            transition = next_transition(report['state'], instance, self._settled.get(name))
            if transition is None or report['state'] == until:
                if report['state'] == 'active':
                    self._settled[name] = instance
                return report
            answer, report = self._transition(name, instance, transition, report['state'])
            reached = report is not None and report['instance'] == instance and \
                report['state'] == STATE_AFTER[transition]
            if not reached and answer is None:
                self.get_logger().warning(f'{name}: no answer to {transition}; asking again '
                                          'at the next check')
                return report
            if not reached and not answer.success:
                self._settled[name] = instance
                self.get_logger().error(f'bringup failed: {name} refused to {transition} '
                                        '(its log says why); it is not asked again until it '
                                        'restarts')
                return report
            # (A refusal with the state reached answers a repeated request.)
            self.get_logger().info(f'{name}: {transition}d')
            if report is None or report['instance'] != instance:
                return report   # silent, or a new process meanwhile: the next check sees

    def _transition(self, name, instance, transition, state_before):
        """Ask node `name` for `transition`; returns (answer or None, its report after).

        DDS drops a request sent before the server has discovered the client (a new
        process, while the killed one's service is still listed): a request unanswered
        for `service_timeout` s is sent again if the node's report shows it still in
        `state_before` (a busy node, one mid-transition, or a reply that was lost are
        waited for, up to `transition_timeout` s). A repeated request that arrives after
        the first has done its work is refused by the node; the caller then reads the
        state reached from the report."""
        client = self._change[name]
        request = transition_request(transition)
        deadline = time.monotonic() + self.values['transition_timeout']
        if not client.wait_for_service(timeout_sec=min(self.values['transition_timeout'],
                                                       5.0)):
            return None, self._reports([name]).get(name)
        future, answered = self._send(client, request)
        while True:
            left = deadline - time.monotonic()
            if answered.wait(max(0.0, min(self.values['service_timeout'], left))):
                return future.result(), self._reports([name]).get(name)
            report = self._reports([name]).get(name)
            if time.monotonic() >= deadline or (
                    report is not None and (report['instance'] != instance or
                                            report['state'] == STATE_AFTER[transition])):
                client.remove_pending_request(future)
                return None, report
            if report is not None and report['state'] == state_before:
                client.remove_pending_request(future)
                self.get_logger().info(f'{name}: no answer to {transition} within '
                                       f'{self.values["service_timeout"]:g} s and still '
                                       f'{state_before}; asking again')
                future, answered = self._send(client, request)

    def _watch_round(self):
        """{node: endpoint report} of the nodes that answered a request sent within the
        last `service_timeout` s.

        Each round asks every node again and waits at most ROUND_WAIT_S: a killed node's
        service stays listed until DDS notices it gone, and a round that waited the full
        `service_timeout` for it saw its respawned process only seconds later (3-5 s per
        kill in the crash test). Answers that come after the round are kept for the next
        one; requests unanswered for `service_timeout` s are given up."""
        timeout = self.values['service_timeout']
        sent = time.monotonic()
        fresh = []
        for name in self.node_names:
            client = self._status[name]
            flights = self._in_flight[name]
            if client.service_is_ready() and len(flights) < MAX_REQUESTS_IN_FLIGHT:
                future, event = self._send(client, Trigger.Request())
                flights.append((sent, future, event))
                fresh.append(event)
        deadline = sent + min(timeout, ROUND_WAIT_S)
        for event in fresh:
            if not event.wait(max(0.0, deadline - time.monotonic())):
                break
        now = time.monotonic()
        reports = {}
        for name, flights in self._in_flight.items():
            waiting = []
            for asked, future, event in flights:
                if event.is_set():
                    self._take_answer(name, asked, future.result())
                elif now - asked > timeout:
                    self._status[name].remove_pending_request(future)
                else:
                    waiting.append((asked, future, event))
            self._in_flight[name] = waiting
            answer = self._answers.get(name)
            if answer is not None and now - answer[0] <= timeout:
                reports[name] = answer[1]
        return reports

    def _take_answer(self, name, asked, result):
        if result is None or asked < self._answers.get(name, (-1.0, None))[0]:
            return
        try:
            self._answers[name] = (asked, json.loads(result.message))
        except ValueError:
            self.get_logger().warning(f'{name}: endpoint_status is not JSON')

    def _reports(self, names):
        """{node: endpoint report} of the nodes that answer, asked all at once."""
        pending = {}
        for name in names:
            client = self._status[name]
            if client.service_is_ready():
                pending[name] = self._send(client, Trigger.Request())
        deadline = time.monotonic() + self.values['service_timeout']
        reports = {}
        for name, (future, event) in pending.items():
            if event.wait(max(0.0, deadline - time.monotonic())) and future.result():
                try:
                    reports[name] = json.loads(future.result().message)
                except ValueError:
                    self.get_logger().warning(f'{name}: endpoint_status is not JSON')
            else:
                self._status[name].remove_pending_request(future)
        return reports

    def _send(self, client, request):
        event = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _: event.set())
        return future, event

    # -- readiness -----------------------------------------------------------------------
    def _update_ready(self, reports):
        waiting = not_active(reports, self.node_names)
        if not waiting:
            waiting = unmatched(reports)
        ready = not waiting
        self._why = '; '.join(waiting) if waiting else ''
        now = time.monotonic()
        if ready != self._ready:
            self._ready_pub.publish(Bool(data=ready))
            if ready:
                self._was_ready = True
                self.get_logger().info(f'{READY_LINE}: {", ".join(self.node_names)} active, '
                                       'their topics matched')
            elif self._ready is not None:
                self.get_logger().warning(f'graph not ready: {self._why}')
            self._last_log = now
        elif not ready and now - self._last_log >= self.values['log_period']:
            self.get_logger().info(f'waiting: {self._why}')
            self._last_log = now
        self._ready = ready


def main(args=None):
    return run_node('lifecycle_manager', LifecycleManager, args,
                    on_exit=lambda node: node.stop())


if __name__ == '__main__':
    sys.exit(main())
