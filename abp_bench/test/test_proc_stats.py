"""proc_stats reads real /proc figures: CPU seconds grow with work, wake-ups with sleeps,
and the abp nodes under a process are found by their installed executable's path."""

import os
import subprocess
import sys
import time

from abp_bench.proc_stats import ProcSample, graph_processes, node_name, rates


def test_cpu_and_wakeups_of_a_process_that_works_then_sleeps():
    child = subprocess.Popen([sys.executable, '-c', (
        'import sys, time\n'
        'sys.stdin.readline()\n'
        't = time.process_time()\n'
        'while time.process_time() - t < 0.3: pass\n'
        'for _ in range(50): time.sleep(0.002)\n'
        'print("done", flush=True)\n'
        'time.sleep(30)\n')], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        before = ProcSample.take(child.pid)
        started = time.monotonic()
        child.stdin.write('go\n')
        child.stdin.flush()
        assert child.stdout.readline().strip() == 'done'
        after = ProcSample.take(child.pid)
        cpu, wakeups, _ = rates(before, after, time.monotonic() - started)
        assert after.cpu_s - before.cpu_s >= 0.2      # the busy loop (from its start on)
        assert after.voluntary - before.voluntary >= 40  # its 50 short sleeps
        assert cpu > 0 and wakeups > 0 and after.threads >= 1
    finally:
        child.kill()
        child.wait()
    assert ProcSample.take(child.pid) is None


def test_nodes_found_by_their_installed_executable(tmp_path):
    exe = tmp_path / 'install' / 'abp_demo' / 'lib' / 'abp_demo' / 'demo_node'
    exe.parent.mkdir(parents=True)
    exe.write_text('import time\ntime.sleep(30)\n')
    shell = subprocess.Popen(['bash', '-c', f'{sys.executable} {exe} & wait'])
    try:
        deadline = time.monotonic() + 10
        found = {}
        while time.monotonic() < deadline and 'demo_node' not in found:
            found = graph_processes(shell.pid)
            time.sleep(0.05)
        assert list(found) == ['demo_node']
        assert node_name(os.getpid()) is None
    finally:
        for pid in found.values():
            os.kill(pid, 9)
        shell.wait()
