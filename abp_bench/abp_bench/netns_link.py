"""Two "hosts" on one Linux machine: two network namespaces joined by a veth pair, with a
rate limit on the link, for running the robot part of the graph in one and the workstation
part in the other (docs/OFFBOARD.md; abp_bench/test/test_two_hosts.py,
abp_bench.link_benchmark).

Each namespace has `lo` and its end of the veth pair, with an address of a private /24
that exists only inside them; nothing of the host's network is reachable from either. A
`tbf` queueing discipline on both ends limits the rate (like a Wi-Fi link's share) and
bounds its queue (packets that would wait longer are dropped). The link can be taken down
and up, and multicast turned off on it (a campus network that filters multicast).

Needs root (CAP_NET_ADMIN and CAP_SYS_ADMIN) and iproute2 (`ip`, `tc`); `unavailable()`
says why not, for a test to skip. The namespaces share the machine's /dev/shm: a process
in one can reach the other over Fast DDS shared memory, so what runs in them must use
UDP only (`FASTDDS_BUILTIN_TRANSPORTS=UDPv4`, `UDP_ONLY`); the interface byte counters
(`counters()`) show what crossed the link.
"""

import json
import os
import pathlib
import secrets
import shutil
import signal
import subprocess
import sys
import time

# Fast DDS's built-in transports: UDP only, no shared memory between the namespaces.
UDP_ONLY = {'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'}
ROBOT, WORKSTATION = 'robot', 'workstation'


def link_environment():
    """The environment of every process on either side of the link: UDP only, and the
    split graph's Fast DDS profile (its 5 s participant lease, abp_bringup
    config/fastdds_link.xml). Every participant needs the same lease: one that keeps a
    longer lease is still "known" to the others when the link comes back after the
    shorter lease ended, and Fast DDS then never exchanges its endpoints again
    (eProsima/Fast-DDS#155, #457): a long-lived client of the robot's services, started
    outside start_graph.sh, would stay deaf."""
    from ament_index_python.packages import get_package_share_directory
    profile = pathlib.Path(get_package_share_directory('abp_bringup')) / 'config' / \
        'fastdds_link.xml'
    return {**UDP_ONLY, 'FASTRTPS_DEFAULT_PROFILES_FILE': str(profile)}


def unavailable():
    """Why two namespaces cannot be made here (a reason to skip), or None."""
    if os.geteuid() != 0:
        return 'network namespaces need root'
    for tool in ('ip', 'tc'):
        if shutil.which(tool) is None:
            return f'iproute2 `{tool}` is not installed'
    probe = f'abp-probe-{secrets.token_hex(3)}'
    made = subprocess.run(['ip', 'netns', 'add', probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f'`ip netns add` failed: {made.stderr.strip()}'
    subprocess.run(['ip', 'netns', 'del', probe], capture_output=True)
    return None


def _run(*argv):
    done = subprocess.run(argv, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f'{" ".join(argv)}: {done.stderr.strip() or done.returncode}')
    return done.stdout


class TwoHostLink:
    """Two namespaces `abp-robot-<id>` / `abp-ws-<id>` joined by veth `abpr<id>` /
    `abpw<id>`, addresses `<subnet>.1` (robot) and `<subnet>.2` (workstation).
    `create()` makes them, `remove()` kills every process left inside them and deletes
    them (the veth pair goes with them); a context manager does both."""

    def __init__(self, rate_mbit=20.0, queue_ms=20.0, subnet='10.77.0', suffix=None):
        suffix = suffix or secrets.token_hex(3)
        self.rate_mbit = float(rate_mbit)
        self.queue_ms = float(queue_ms)
        self.namespace = {ROBOT: f'abp-robot-{suffix}', WORKSTATION: f'abp-ws-{suffix}'}
        # Interface names have at most 15 characters.
        self.interface = {ROBOT: f'abpr{suffix}', WORKSTATION: f'abpw{suffix}'}
        self.address = {ROBOT: f'{subnet}.1', WORKSTATION: f'{subnet}.2'}
        self._made = []
        self._multicast = True

    def __enter__(self):
        self.create()
        return self

    def __exit__(self, *exc):
        self.remove()

    def create(self):
        try:
            for side in (ROBOT, WORKSTATION):
                _run('ip', 'netns', 'add', self.namespace[side])
                self._made.append(self.namespace[side])
            _run('ip', 'link', 'add', self.interface[ROBOT], 'type', 'veth', 'peer', 'name',
                 self.interface[WORKSTATION])
            # The burst a token bucket needs at this rate (at least one 1500-byte frame per
            # timer tick); the latency bounds the queue.
            burst = max(int(self.rate_mbit * 1e6 / 8 / 250), 3200)
            for side in (ROBOT, WORKSTATION):
                ns, dev = self.namespace[side], self.interface[side]
                _run('ip', 'link', 'set', dev, 'netns', ns)
                _run('ip', '-n', ns, 'addr', 'add', f'{self.address[side]}/24', 'dev', dev)
                _run('ip', '-n', ns, 'link', 'set', 'lo', 'up')
                _run('ip', '-n', ns, 'link', 'set', dev, 'up')
                self._route_multicast(side)
                _run('tc', '-n', ns, 'qdisc', 'add', 'dev', dev, 'root', 'tbf', 'rate',
                     f'{self.rate_mbit:g}mbit', 'burst', str(burst),
                     'latency', f'{self.queue_ms:g}ms')
        except Exception:
            self.remove()
            raise
        return self

    def _route_multicast(self, side):
        # DDS discovery's multicast (239.255.0.1) leaves by the link: the namespace has no
        # default route. (A link taken down loses this route; `set_up` puts it back.)
        _run('ip', '-n', self.namespace[side], 'route', 'replace', '224.0.0.0/4', 'dev',
             self.interface[side])

    def remove(self):
        """Kill what still runs in the namespaces, then delete them (and the link)."""
        for ns in self._made:
            for _ in range(20):
                pids = subprocess.run(['ip', 'netns', 'pids', ns], capture_output=True,
                                      text=True).stdout.split()
                if not pids:
                    break
                for pid in pids:
                    try:
                        os.kill(int(pid), signal.SIGKILL)
                    except (ProcessLookupError, ValueError):
                        pass
                time.sleep(0.05)   # the kernel reaps them; then look again
            subprocess.run(['ip', 'netns', 'del', ns], capture_output=True)
        self._made = []

    def command(self, side, argv):
        """`argv` run inside the namespace of `side`."""
        return ['ip', 'netns', 'exec', self.namespace[side], *map(str, argv)]

    def counters(self, side):
        """{'rx_bytes', 'tx_bytes', 'rx_packets', 'tx_packets', 'tx_dropped'} of the
        link's end on `side` (the kernel's interface statistics; a veth counts no
        multicast)."""
        out = _run('ip', '-n', self.namespace[side], '-s', '-j', 'link', 'show', 'dev',
                   self.interface[side])
        stats = json.loads(out)[0]['stats64']
        return {'rx_bytes': stats['rx']['bytes'], 'tx_bytes': stats['tx']['bytes'],
                'rx_packets': stats['rx']['packets'], 'tx_packets': stats['tx']['packets'],
                'tx_dropped': stats['tx']['dropped']}

    def set_up(self, up):
        """Take the link down (both ends, as a lost radio link) or bring it up again."""
        for side in (ROBOT, WORKSTATION):
            _run('ip', '-n', self.namespace[side], 'link', 'set', self.interface[side],
                 'up' if up else 'down')
            if up and self._multicast:
                self._route_multicast(side)

    def set_multicast(self, on):
        """Multicast on or off on the link: the interfaces' flag, and the route multicast
        leaves by (without it a multicast send finds no route, as on a network that
        filters multicast)."""
        self._multicast = bool(on)
        for side in (ROBOT, WORKSTATION):
            ns, dev = self.namespace[side], self.interface[side]
            _run('ip', '-n', ns, 'link', 'set', 'dev', dev, 'multicast', 'on' if on else 'off')
            if on:
                self._route_multicast(side)
            else:
                subprocess.run(['ip', '-n', ns, 'route', 'del', '224.0.0.0/4', 'dev', dev],
                               capture_output=True)

    def multicast_reaches(self, side):
        """Whether a UDP datagram to DDS's discovery multicast group can leave `side`."""
        send = ('import socket; socket.socket(socket.AF_INET, socket.SOCK_DGRAM)'
                '.sendto(b"probe", ("239.255.0.1", 7400))')
        return subprocess.run(self.command(side, [sys.executable, '-c', send]),
                              capture_output=True).returncode == 0

    def shared_memory_files(self, side):
        """The /dev/shm files that the processes in the namespace of `side` map (Fast DDS's
        shared-memory transport and data sharing would show as fastrtps_* and
        fast_datasharing* there)."""
        pids = subprocess.run(['ip', 'netns', 'pids', self.namespace[side]],
                              capture_output=True, text=True).stdout.split()
        files = set()
        for pid in pids:
            try:
                with open(f'/proc/{pid}/maps') as maps:
                    files.update(line.split()[-1] for line in maps if '/dev/shm/' in line)
            except OSError:
                pass   # gone meanwhile
        return files

    def sockets(self, side):
        """The UDP sockets open in the namespace of `side` (`ss -uan` lines)."""
        return _run('ip', 'netns', 'exec', self.namespace[side], 'ss', '-uanp').splitlines()


__all__ = ['ROBOT', 'UDP_ONLY', 'WORKSTATION', 'TwoHostLink', 'link_environment',
           'unavailable']
