"""Shared pytest fixtures for every package's tests and the repo-level system tests.

ROS isolation: each pytest session gets its own ROS_DOMAIN_ID and localhost-only
discovery, set before any rclpy context exists, and inherited by every process a
test starts. Processes started through `ros_processes` are killed (their whole
process group) when the test ends, whatever its outcome.
"""

import os
import pathlib
import random
import select
import signal
import subprocess
import sys
import time

import pytest


def _domains_in_use():
    """ROS_DOMAIN_IDs in the environment of other processes of this machine (other test
    sessions, their graphs): a session that shared one would talk to their nodes."""
    used = set()
    for proc in pathlib.Path('/proc').glob('[0-9]*'):
        try:
            environ = (proc / 'environ').read_bytes()
        except OSError:
            continue  # gone meanwhile, or not ours to read
        for entry in environ.split(b'\0'):
            if entry.startswith(b'ROS_DOMAIN_ID='):
                used.add(entry[len(b'ROS_DOMAIN_ID='):].decode(errors='replace'))
    return used


# Chosen at import, before any test can initialise rclpy. Domain ids 1..101 keep
# the default port mapping valid; the pid spreads concurrent sessions apart, and a
# domain another process already uses is skipped while a free one is left.
_start = os.getpid() + random.SystemRandom().randrange(101)
_in_use = _domains_in_use()
_DOMAIN_ID = next((1 + (_start + i) % 101 for i in range(101)
                   if str(1 + (_start + i) % 101) not in _in_use), 1 + _start % 101)
os.environ['ROS_DOMAIN_ID'] = str(_DOMAIN_ID)
# Marks every process this session starts (they inherit it), so that a clean-up kills
# only those, never another session's that happens to share the domain.
os.environ['ABP_TEST_SESSION'] = f'{os.getpid()}-{random.SystemRandom().getrandbits(48):x}'
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_LOCALHOST_ONLY', None)  # deprecated in Jazzy, conflicts with the above
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
os.environ['PYTHONUNBUFFERED'] = '1'


class ProcessGroup:
    """Starts child processes in their own sessions and guarantees their cleanup."""

    def __init__(self):
        self.processes = []
        self._unread = {}  # pid -> output read from the pipe but not yet returned
        self._read = {}  # pid -> all output read from the pipe so far (for failure reports)
        self.log_files = {}  # pid -> the file a process writes its output to

    def start(self, argv, **kwargs):
        """Popen with the output on a pipe; a process whose environment names a `LOG` file
        (a test that redirects a node's output there) has that file's tail in the report
        of a failed test."""
        env = kwargs.pop('env', None)
        env = os.environ.copy() if env is None else env
        proc = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
            env=env,
            **kwargs,
        )
        self.processes.append(proc)
        if env.get('LOG'):
            self.log_files[proc.pid] = env['LOG']
        return proc

    def start_python(self, script, *args, **kwargs):
        return self.start([sys.executable, str(script), *map(str, args)], **kwargs)

    def stop_all(self, timeout=5.0):
        for proc in self.processes:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        deadline = time.monotonic() + timeout
        for proc in self.processes:
            remaining = max(0.1, deadline - time.monotonic())
            try:
                proc.wait(timeout=remaining)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=5)
        for proc in self.processes:
            # The group may hold grandchildren; make sure none outlives the test.
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

    def wait_for_line(self, proc, text, timeout):
        """Read `proc`'s output until a line contains `text`; returns the lines read.

        Reads the pipe's file descriptor directly: a buffered readline could hold
        the awaited line in its buffer while select() reports the pipe idle.
        """
        pending = self._unread.pop(proc.pid, '')
        lines = []
        deadline = time.monotonic() + timeout
        while True:
            while '\n' in pending:
                line, pending = pending.split('\n', 1)
                lines.append(line + '\n')
                if text in line:
                    self._unread[proc.pid] = pending
                    return lines
            if time.monotonic() >= deadline:
                break
            ready, _, _ = select.select([proc.stdout], [], [], 0.1)
            if ready:
                chunk = os.read(proc.stdout.fileno(), 65536)
                if not chunk:
                    break  # the process closed its output
                text_read = chunk.decode(errors='replace')
                self._read[proc.pid] = self._read.get(proc.pid, '') + text_read
                pending += text_read
            elif proc.poll() is not None:
                break
        self._unread[proc.pid] = pending
        raise AssertionError(
            f"{proc.args!r} did not print {text!r} within {timeout} s "
            f"(exit code {proc.poll()}); output so far:\n{''.join(lines)}{pending}")

    def wait_for_lines(self, proc, texts, timeout):
        """Read `proc`'s output until each of `texts` has been in a line, in any order;
        returns the lines read."""
        deadline = time.monotonic() + timeout
        lines, missing = [], list(texts)
        while missing:
            lines += self.wait_for_line(proc, missing[0], max(deadline - time.monotonic(), 0))
            missing = [t for t in missing if not any(t in line for line in lines)]
        return lines

    def output(self, proc):
        """All output of a finished (or stopped) process not yet read by wait_for_line."""
        if proc.stdout is None:
            return ''
        rest = proc.stdout.read()
        self._read[proc.pid] = self._read.get(proc.pid, '') + rest
        return self._unread.pop(proc.pid, '') + rest

    def transcript(self, proc):
        """Everything a stopped process printed, including what wait_for_line read."""
        self.output(proc)
        return self._read.get(proc.pid, '')


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item, call):
    # Kept on the item so that a fixture's teardown can tell whether the test failed.
    report = yield
    setattr(item, f'abp_report_{report.when}', report)
    return report


@pytest.fixture
def ros_processes(request):
    group = ProcessGroup()
    yield group
    group.stop_all()
    report = getattr(request.node, 'abp_report_call', None)
    if report is not None and report.failed:
        # What the nodes said is what explains a failure over DDS: shown with the report.
        for proc in group.processes:
            lines = group.transcript(proc).splitlines()[-80:]
            log_file = group.log_files.get(proc.pid)
            if log_file and os.path.exists(log_file):
                with open(log_file, errors='replace') as log:
                    lines += log.read().splitlines()[-80:]
            print(f'--- output of {" ".join(map(str, proc.args))[:160]} '
                  f'(exit code {proc.returncode}), last {len(lines)} lines ---')
            print('\n'.join(lines))


@pytest.fixture
def rclpy_context():
    """An rclpy context of this test only, on the session's isolated domain."""
    rclpy = pytest.importorskip('rclpy')
    context = rclpy.context.Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


@pytest.fixture
def main_in_process(capsys):
    """`run(main, *ros_args)`: a node's `main()` run in this process (the code path of its
    executable, without the process start-up) -> (exit code, stderr). For configuration
    errors, which end main() before any spin; a main() that spins instead (the value was
    taken) is ended after `timeout` s by shutting rclpy down, and returns 0. SIGINT's
    handler (run_node sets its own) is restored."""
    import threading

    def run(main, *ros_args, timeout=30.0):
        rclpy = pytest.importorskip('rclpy')
        previous = signal.getsignal(signal.SIGINT)
        capsys.readouterr()
        stop = threading.Timer(timeout, rclpy.try_shutdown)
        stop.start()
        try:
            code = main(['node', '--ros-args', *ros_args])
        finally:
            stop.cancel()
            signal.signal(signal.SIGINT, previous)
        return code, capsys.readouterr().err
    return run


@pytest.fixture
def tester(rclpy_context):
    """(node, executor): a test's own node in `rclpy_context` on a single-threaded
    executor, destroyed at teardown."""
    rclpy = pytest.importorskip('rclpy')
    from rclpy.executors import SingleThreadedExecutor
    node = rclpy.create_node('tester', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()


def spin_until(executor, predicate, timeout):
    """Spin `executor` until `predicate()` is true or `timeout` seconds pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        executor.spin_once(timeout_sec=0.05)
    return predicate()


@pytest.fixture
def spin():
    return spin_until


def action_server_answers(executor, action_client, timeout):
    """Spin until the action server has answered a handshake (a goal sent after it is
    not lost in DDS discovery: abp_common.server_handshake)."""
    from abp_common.server_handshake import wait_until_answering
    return wait_until_answering(
        action_client, lambda done, seconds: spin_until(executor, done, seconds), timeout)


@pytest.fixture
def answering():
    return action_server_answers


def call_until_answered(executor, client, request, timeout, attempt_s=3.0, ready_timeout=None):
    """Call a service that is safe to ask twice, asking again every `attempt_s` for up to
    `timeout` s once the service is there (within `ready_timeout`, default `timeout`): DDS
    drops a reply to a client the server has not discovered yet. Returns the response."""
    assert spin_until(executor, client.service_is_ready,
                      timeout if ready_timeout is None else ready_timeout), \
        f'no {client.srv_name} service'
    deadline = time.monotonic() + timeout
    while True:
        future = client.call_async(request)
        if spin_until(executor, future.done, attempt_s):
            return future.result()
        client.remove_pending_request(future)
        assert time.monotonic() < deadline, f'{client.srv_name} did not answer in {timeout} s'


@pytest.fixture
def call_service():
    return call_until_answered
