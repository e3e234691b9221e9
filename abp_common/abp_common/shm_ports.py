"""Fast DDS shared-memory ports left by a killed process: retire them before a respawn.

Fast DDS (2.14, the Jazzy wheels) gives each participant a shared-memory *port* per
unicast locator: a ring buffer in /dev/shm/fastrtps_port<N>, read by the participant
that holds the flock on /dev/shm/fastrtps_port<N>_el, written by every participant that
sends to it. A writer keeps the port it opened for as long as it lives, and opens it
again only once the port is marked not ok (SharedMemTransport::push_discard). A respawned
process takes the dead one's participant id, so the same port number: it finds the port
a zombie (the `_el` file is not locked), removes the segment and creates a new one, but
does not mark the old one not ok. The writers' watchdog marks it not ok only if the dead
reader was caught waiting (its counter stops) or processing (the same buffer twice); a
reader killed between two messages looks alive forever. Every process that had sent to
the dead node then keeps writing into the removed segment, and nothing it sends reaches
the new process: its service requests, and its discovery data if the port is the
metatraffic one (docs/RECOVERY.md; `abp_bench.respawn_probe` reproduces it).

`retire_zombie_ports()` does the step Fast DDS leaves out, before this process creates
its participant (`node_runner.run_node`): every port whose reader is dead (its `_el` file
exists and can be locked) is marked not ok, so each writer opens it afresh on its next
send (Fast DDS's own regenerate path) and reaches whoever listens on it now.
The layout read here is Fast DDS 2.14's SharedMemGlobal::PortNode (ABI 5); a segment
that does not name that ABI is left alone.
"""

import fcntl
import os
import pathlib
import re
import struct

SHM_DIR = pathlib.Path('/dev/shm')
PORT_FILE = re.compile(r'^fastrtps_port(\d+)_el$')
ABI_MARK = b'port_node_abi5\0'
DOMAIN_NAME = b'fastrtps\0'
# PortNode: port_id, num_listeners, healthy_check_timeout_ms, port_wait_timeout_ms
# (= healthy / 3), max_buffer_descriptors, waiting_count, then the flags word
# (bit 0 is_port_ok, bit 1 is_opened_read_exclusive, bit 2 is_opened_for_reading).
PORT_FIELDS = struct.Struct('<6I')
FLAGS = struct.Struct('<I')
PORT_OK = 0b1
# ... and, before the domain name, 1024 listener status entries of 20 bytes: a flags byte
# (bit 0 in use, bit 1 waiting, bit 2 processing), a counters byte, a buffer descriptor.
LISTENER_SLOTS = 1024
LISTENER_STATUS_BYTES = 20


def port_node_offset(data, port_id):
    """Offset of the PortNode of `port_id` in a port segment's bytes, or None."""
    if ABI_MARK not in data:
        return None
    start = 0
    key = struct.pack('<I', port_id)
    while (at := data.find(key, start)) != -1 and at + PORT_FIELDS.size + 4 <= len(data):
        _, listeners, healthy_ms, wait_ms, capacity, _ = PORT_FIELDS.unpack_from(data, at)
        if healthy_ms > 0 and wait_ms == healthy_ms // 3 and capacity > 0 and \
                listeners <= LISTENER_SLOTS:
            return at
        start = at + 1
    return None


def mark_port_not_ok(path, port_id):
    """Clear is_port_ok in the port segment at `path`; True if it was ok before."""
    with open(path, 'r+b') as segment:
        data = segment.read()
        at = port_node_offset(data, port_id)
        if at is None:
            return False
        flags_at = at + PORT_FIELDS.size
        (flags,) = FLAGS.unpack_from(data, flags_at)
        if not flags & PORT_OK:
            return False
        segment.seek(flags_at)
        segment.write(FLAGS.pack(flags & ~PORT_OK))
        return True


def retire_zombie_ports(shm_dir=SHM_DIR):
    """Mark not ok every shared-memory port whose reading process is dead; returns their
    port numbers. A port whose reader is alive (its `_el` flock is held) is not touched,
    nor is one without an `_el` file (a clean close removes it)."""
    retired = []
    try:
        names = os.listdir(shm_dir)
    except OSError:
        return retired
    for name in sorted(names):
        match = PORT_FILE.match(name)
        if match is None:
            continue
        port_id = int(match.group(1))
        lock_path = os.path.join(shm_dir, name)
        try:
            lock = os.open(lock_path, os.O_RDONLY)
        except OSError:
            continue
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(lock)
            continue        # a live reader holds it
        try:
            # Held by us now, so no process can take the port meanwhile; as in Fast DDS's
            # own lock, a file removed between open and lock is not a zombie.
            if os.path.exists(lock_path) and \
                    mark_port_not_ok(os.path.join(shm_dir, name[:-len('_el')]), port_id):
                retired.append(port_id)
        except OSError:
            pass            # the segment is gone, or not ours to write
        finally:
            os.close(lock)  # closing releases the flock
    return retired


def freeze_listeners_between_messages(path):
    """Fault injection (tests, `abp_bench.respawn_probe`): make the listeners of the port
    segment at `path` look killed between two messages (in use, neither waiting nor
    processing), the state Fast DDS's watchdog cannot tell from a live listener. Call it
    after the reading process was killed. Returns how many listeners were changed."""
    with open(path, 'r+b') as segment:
        data = segment.read()
        if ABI_MARK not in data:
            return 0
        domain = data.find(DOMAIN_NAME, LISTENER_SLOTS * LISTENER_STATUS_BYTES)
        if domain == -1:
            return 0
        base = domain - LISTENER_SLOTS * LISTENER_STATUS_BYTES
        changed = 0
        for slot in range(LISTENER_SLOTS):
            at = base + slot * LISTENER_STATUS_BYTES
            if data[at] & 0b001 and data[at] & 0b110:
                segment.seek(at)
                segment.write(bytes([data[at] & 0b001]))
                changed += 1
        return changed


__all__ = ['freeze_listeners_between_messages', 'mark_port_not_ok', 'port_node_offset',
           'retire_zombie_ports']
