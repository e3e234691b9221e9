"""shm_ports without DDS: which ports are retired, and what is written.

The segments here are built by hand with Fast DDS 2.14's PortNode fields at the place a
real port segment has them (offset 276, as in /dev/shm/fastrtps_port*); the layout of a
real segment is checked over DDS by abp_bringup/test/test_respawn_shared_memory.py."""

import fcntl
import os
import struct

from abp_common.shm_ports import (
    ABI_MARK,
    DOMAIN_NAME,
    FLAGS,
    LISTENER_SLOTS,
    LISTENER_STATUS_BYTES,
    PORT_FIELDS,
    freeze_listeners_between_messages,
    retire_zombie_ports,
)

PORT_NODE_AT = 276
OK_EXCLUSIVE_READING = 0b111


def write_segment(path, port_id, flags=OK_EXCLUSIVE_READING, listener_flags=0b011):
    data = bytearray(PORT_NODE_AT + PORT_FIELDS.size + 4 + 64
                     + LISTENER_SLOTS * LISTENER_STATUS_BYTES + 64)
    data[16:16 + len(ABI_MARK)] = ABI_MARK
    # An earlier occurrence of the port number that is not a PortNode must be skipped.
    data[100:104] = struct.pack('<I', port_id)
    PORT_FIELDS.pack_into(data, PORT_NODE_AT, port_id, 1, 1000, 333, 512, 1)
    FLAGS.pack_into(data, PORT_NODE_AT + PORT_FIELDS.size, flags)
    listeners = PORT_NODE_AT + PORT_FIELDS.size + 4 + 64
    data[listeners] = listener_flags
    domain = listeners + LISTENER_SLOTS * LISTENER_STATUS_BYTES
    data[domain:domain + len(DOMAIN_NAME)] = DOMAIN_NAME
    path.write_bytes(bytes(data))
    return listeners


def flags_of(path):
    return FLAGS.unpack_from(path.read_bytes(), PORT_NODE_AT + PORT_FIELDS.size)[0]


def test_only_ports_whose_reader_is_gone_are_marked_not_ok(tmp_path):
    for port in (7411, 7413, 7415, 7417):
        write_segment(tmp_path / f'fastrtps_port{port}', port)
    for port in (7411, 7413, 7417):
        (tmp_path / f'fastrtps_port{port}_el').touch()
    # 7413's reader is alive: it holds the flock (on its own open file, as Fast DDS does).
    alive = os.open(tmp_path / 'fastrtps_port7413_el', os.O_RDONLY)
    fcntl.flock(alive, fcntl.LOCK_EX | fcntl.LOCK_NB)
    # 7417 was already marked not ok by Fast DDS's own watchdog.
    write_segment(tmp_path / 'fastrtps_port7417', 7417, flags=0b110)
    try:
        assert retire_zombie_ports(tmp_path) == [7411]
        assert flags_of(tmp_path / 'fastrtps_port7411') == 0b110    # only is_port_ok cleared
        assert flags_of(tmp_path / 'fastrtps_port7413') == OK_EXCLUSIVE_READING
        assert flags_of(tmp_path / 'fastrtps_port7415') == OK_EXCLUSIVE_READING  # no _el
        # Retired once: the next start finds nothing left to do.
        assert retire_zombie_ports(tmp_path) == []
    finally:
        os.close(alive)
    # 7413's reader has died meanwhile: the next start retires its port, and leaves the
    # lock free for the process that takes the port.
    assert retire_zombie_ports(tmp_path) == [7413]
    probe = os.open(tmp_path / 'fastrtps_port7413_el', os.O_RDONLY)
    try:
        fcntl.flock(probe, fcntl.LOCK_EX | fcntl.LOCK_NB)
    finally:
        os.close(probe)


def test_a_segment_of_another_fast_dds_abi_is_left_alone(tmp_path):
    path = tmp_path / 'fastrtps_port7411'
    write_segment(path, 7411)
    path.write_bytes(path.read_bytes().replace(ABI_MARK, b'port_node_abi9\0'))
    (tmp_path / 'fastrtps_port7411_el').touch()
    assert retire_zombie_ports(tmp_path) == []
    assert flags_of(path) == OK_EXCLUSIVE_READING
    assert retire_zombie_ports(tmp_path / 'missing') == []


def test_freezing_a_listener_clears_waiting_and_processing_only(tmp_path):
    path = tmp_path / 'fastrtps_port7411'
    listeners = write_segment(path, 7411, listener_flags=0b011)
    assert freeze_listeners_between_messages(path) == 1
    assert path.read_bytes()[listeners] == 0b001
    assert freeze_listeners_between_messages(path) == 0     # nothing waiting any more
