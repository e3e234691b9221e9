"""CPU time and wake-ups of processes from /proc (plain Python, no rclpy, no psutil).

`graph_processes(root_pid)` finds the abp nodes started under a process (start_graph.sh):
each is named by its installed executable (`.../install/<pkg>/lib/<pkg>/<exe>`).
`ProcSample.take(pid)` reads one process's CPU seconds (user + system, all threads, from
/proc/<pid>/stat) and context switches summed over its threads (/proc/<pid>/task/*/status:
the process's own status counts only the main thread). A voluntary switch is a thread
giving up the CPU to wait (a wake-up when it resumes); the difference of two samples over
a window gives CPU % of one core and wake-ups per second.
"""

import os
import pathlib
from dataclasses import dataclass

CLOCK_TICKS = os.sysconf('SC_CLK_TCK')


def _children(pid):
    """Direct children of `pid` (Linux 3.5+: /proc/<pid>/task/<tid>/children)."""
    kids = []
    for task in pathlib.Path(f'/proc/{pid}/task').glob('*'):
        try:
            kids += [int(c) for c in (task / 'children').read_text().split()]
        except OSError:
            continue
    return kids


def descendants(pid):
    found, todo = [], [pid]
    while todo:
        for child in _children(todo.pop()):
            found.append(child)
            todo.append(child)
    return found


def node_name(pid):
    """The executable name of an installed abp node process, else None."""
    try:
        argv = pathlib.Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
    except OSError:
        return None
    for arg in argv[:3]:
        text = arg.decode(errors='replace')
        if ' ' in text:          # a shell's command string, not an executable's path
            continue
        parts = text.split('/')
        if len(parts) >= 5 and parts[-5] == 'install' and parts[-3] == 'lib':
            return parts[-1]
    return None


def graph_processes(root_pid):
    """{node name: pid} of the abp nodes under `root_pid` (its own pid included)."""
    found = {}
    for pid in [root_pid] + descendants(root_pid):
        name = node_name(pid)
        if name is not None:
            found[name] = pid
    return found


@dataclass
class ProcSample:
    cpu_s: float
    voluntary: int
    involuntary: int
    threads: int

    @classmethod
    def take(cls, pid):
        """None when the process is gone."""
        try:
            stat = pathlib.Path(f'/proc/{pid}/stat').read_text()
            fields = stat[stat.rindex(')') + 2:].split()
            cpu_s = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime
            voluntary = involuntary = threads = 0
            for task in pathlib.Path(f'/proc/{pid}/task').glob('*'):
                try:
                    text = (task / 'status').read_text()
                except OSError:
                    continue
                threads += 1
                for line in text.splitlines():
                    if line.startswith('voluntary_ctxt_switches:'):
                        voluntary += int(line.split()[1])
                    elif line.startswith('nonvoluntary_ctxt_switches:'):
                        involuntary += int(line.split()[1])
            return cls(cpu_s, voluntary, involuntary, threads)
        except (OSError, ValueError, IndexError):
            return None


def rates(before, after, wall_s):
    """(CPU % of one core, wake-ups per second, involuntary switches per second).
    Threads that ended in the window take their switches with them: a rate is then a
    lower bound (never negative)."""
    return (100.0 * (after.cpu_s - before.cpu_s) / wall_s,
            max(0, after.voluntary - before.voluntary) / wall_s,
            max(0, after.involuntary - before.involuntary) / wall_s)


def load_average():
    """The 1-minute load average and the number of CPUs (the machine's business)."""
    return os.getloadavg()[0], os.cpu_count()


__all__ = ['ProcSample', 'descendants', 'graph_processes', 'load_average', 'node_name',
           'rates']
