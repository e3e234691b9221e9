"""For the system tests that start whole graphs: find the processes a test of this
session left, and run a graph script to its end under a deadline that stops it
and everything it started, instead of orphaning them.

Why both: pytest-timeout ends a test by raising in its thread, and `subprocess.run` then
SIGKILLs only its direct child. A graph left running keeps publishing /clock on the
session's domain, and every later test of the session then sees its clock jump."""

import os
import pathlib
import re
import signal
import subprocess
import time

# Command-line markers of the processes a graph test starts: the nodes (installed
# executables), start_graph.sh with its supervisor subshells, and the soak driver.
GRAPH_MARKERS = (b'/install/abp_', b'scripts/start_graph.sh', b'abp_bench.soak')


def graph_processes(with_pids=False, markers=(b'/install/abp_',)):
    """Processes of this test session (their environment holds its ABP_TEST_SESSION, set
    by the root conftest) whose command line holds one of `markers` (by default: abp
    executables), as command lines or (pid, command line). Not every process on the
    session's ROS domain: another session may share it, and its processes are not ours."""
    session = f"ABP_TEST_SESSION={os.environ['ABP_TEST_SESSION']}".encode()
    found = []
    for proc in pathlib.Path('/proc').glob('[0-9]*'):
        if proc.name == str(os.getpid()):
            continue
        try:
            cmdline = (proc / 'cmdline').read_bytes()
            environ = (proc / 'environ').read_bytes()
        except OSError:
            continue  # gone meanwhile, or not ours to read
        if any(m in cmdline for m in markers) and session in environ.split(b'\0'):
            text = cmdline.replace(b'\0', b' ').decode(errors='replace').strip()
            found.append((int(proc.name), text) if with_pids else text)
    return found


def dds_transports(pid):
    """How process `pid` talks DDS: (its Fast DDS shared-memory threads, the local
    addresses of its UDP sockets as /proc/net/udp writes them, e.g. '0100007F' for
    127.0.0.1). Fast DDS names a thread per transport port it listens on: dds.shm.<port>,
    dds.udp.<port>."""
    proc = pathlib.Path(f'/proc/{pid}')
    shm = []
    for task in (proc / 'task').iterdir():
        try:
            name = (task / 'comm').read_text().strip()
        except OSError:
            continue
        if name.startswith('dds.shm'):
            shm.append(name)
    sockets = set()
    for fd in (proc / 'fd').iterdir():
        try:
            match = re.fullmatch(r'socket:\[(\d+)\]', os.readlink(fd))
        except OSError:
            continue
        if match:
            sockets.add(match.group(1))
    addresses = set()
    for line in (proc / 'net' / 'udp').read_text().splitlines()[1:]:
        fields = line.split()
        if fields[9] in sockets:
            addresses.add(fields[1].split(':')[0])
    return shm, addresses


def kill_leftovers(rounds=20):
    """SIGKILL every graph process left on this session's domain, with its process group;
    returns their command lines. Scans again until none is left: a supervisor or a
    script may have started a process between a scan and its kill."""
    own_group = os.getpgrp()
    killed = {}
    for _ in range(rounds):
        left = graph_processes(with_pids=True, markers=GRAPH_MARKERS)
        if not left:
            break
        for pid, cmdline in left:
            killed.setdefault(pid, cmdline)
            try:
                group = os.getpgid(pid)
                if group != own_group:
                    os.killpg(group, signal.SIGKILL)
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        time.sleep(0.1)  # lets the kernel finish the kills before the next scan
    return list(killed.values())


def stop_group(proc, int_grace=60.0, term_grace=20.0):
    """Stop `proc` (started in its own session) as Ctrl-C would: SIGINT to its process
    group, then SIGTERM, then SIGKILL, each after a grace period."""
    for sig, grace in ((signal.SIGINT, int_grace), (signal.SIGTERM, term_grace)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=grace)
            return
        except subprocess.TimeoutExpired:
            pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


def run_to_end(argv, timeout, output_path):
    """Run `argv` in its own session with its output in `output_path`; past `timeout`
    seconds stop it (stop_group). Returns (exit code, output, whether it timed out)."""
    with open(output_path, 'w') as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, text=True,
                                start_new_session=True)
        started = time.monotonic()
        try:
            proc.wait(timeout=timeout)
            timed_out = False
        except subprocess.TimeoutExpired:
            timed_out = True
        finally:
            # Also on an exception (pytest-timeout): never leave the group running.
            if proc.poll() is None:
                stop_group(proc)
    output = pathlib.Path(output_path).read_text(errors='replace')
    if timed_out:
        output += (f'\n[test] stopped after {time.monotonic() - started:.0f} s: no end '
                   f'within {timeout:.0f} s\n')
    return proc.returncode, output, timed_out


def node_log_tails(log_dir, lines=30):
    """The last `lines` lines of each node log in `log_dir`, for a failure report."""
    parts = []
    for log in sorted(pathlib.Path(log_dir).glob('*.log')):
        tail = log.read_text(errors='replace').splitlines()[-lines:]
        parts.append(f'\n--- {log.name} (last {len(tail)} lines) ---\n' + '\n'.join(tail))
    return ''.join(parts)
