"""Joint positions at an image stamp from buffered joint states
(abp_perception.joint_state_buffer)."""

import pytest

from abp_perception.joint_state_buffer import JointStateBuffer, OutsideBuffer

MS = 1_000_000


def moving_head(buffer, start_ms=1000, end_ms=3000, period_ms=10, speed=0.5):
    """head_pan at `speed` rad/s from 0 at start_ms; torso still."""
    for t in range(start_ms, end_ms + 1, period_ms):
        buffer.add(t * MS, ['head_pan_joint', 'torso_pitch_joint'],
                   [speed * (t - start_ms) * 1e-3, 0.1])


def test_between_samples_the_position_is_interpolated():
    buffer = JointStateBuffer(duration_s=2.0, tolerance_s=0.02)
    moving_head(buffer)
    found = buffer.at(2_937_500_000, ['head_pan_joint', 'torso_pitch_joint'])
    assert found.positions['head_pan_joint'] == pytest.approx(0.5 * 1.9375)
    assert found.positions['torso_pitch_joint'] == pytest.approx(0.1)
    assert found.worst_gap_s == 0.0 and found.unstamped == ()


def test_within_the_tolerance_the_edge_sample_is_held_and_beyond_it_refused():
    buffer = JointStateBuffer(duration_s=2.0, tolerance_s=0.02)
    moving_head(buffer)
    found = buffer.at(3015 * MS, ['head_pan_joint'])
    assert found.positions['head_pan_joint'] == pytest.approx(1.0)
    assert found.worst_gap_s == pytest.approx(0.015)
    with pytest.raises(OutsideBuffer, match=r'0\.030 s after the newest head_pan_joint'):
        buffer.at(3030 * MS, ['head_pan_joint'])
    with pytest.raises(OutsideBuffer, match='before the oldest'):
        buffer.at(900 * MS, ['head_pan_joint'])


def test_only_the_last_seconds_are_kept():
    buffer = JointStateBuffer(duration_s=0.5, tolerance_s=0.0)
    moving_head(buffer)
    first, last = buffer.span_ns('head_pan_joint')
    assert last == 3000 * MS and first == 2500 * MS
    with pytest.raises(OutsideBuffer):
        buffer.at(2400 * MS, ['head_pan_joint'])


def test_joints_from_separate_publishers_are_interpolated_separately():
    buffer = JointStateBuffer(duration_s=2.0, tolerance_s=0.0)
    buffer.add(100 * MS, ['a'], [0.0])
    buffer.add(105 * MS, ['b'], [10.0])
    buffer.add(200 * MS, ['a'], [1.0])
    buffer.add(305 * MS, ['b'], [20.0])
    found = buffer.at(150 * MS, ['a', 'b', 'never_seen'])
    assert found.positions == pytest.approx({'a': 0.5, 'b': 12.25})


def test_out_of_order_samples_are_placed_by_stamp():
    buffer = JointStateBuffer()
    for t in (100, 300, 200):
        buffer.add(t * MS, ['a'], [float(t)])
    assert buffer.at(250 * MS, ['a']).positions['a'] == pytest.approx(250.0)


def test_a_clock_that_restarts_starts_the_buffer_again():
    buffer = JointStateBuffer(duration_s=1.0, tolerance_s=0.0)
    moving_head(buffer, 100_000, 101_000)
    buffer.add(5 * MS, ['head_pan_joint'], [0.2])          # a restarted simulation
    assert buffer.span_ns('head_pan_joint') == (5 * MS, 5 * MS)
    assert buffer.at(5 * MS, ['head_pan_joint']).positions['head_pan_joint'] == 0.2


def test_unstamped_joint_states_are_taken_as_they_are_and_flagged():
    buffer = JointStateBuffer()
    moving_head(buffer)
    buffer.add(0, ['head_pan_joint'], [0.7])
    found = buffer.at(2000 * MS, ['head_pan_joint', 'torso_pitch_joint'])
    assert found.positions['head_pan_joint'] == 0.7 and found.unstamped == ('head_pan_joint',)
    assert found.positions['torso_pitch_joint'] == pytest.approx(0.1)
    assert buffer.at(123 * MS, ['head_pan_joint']).positions['head_pan_joint'] == 0.7
    with pytest.raises(OutsideBuffer):                     # torso is still stamped
        buffer.at(123 * MS, ['torso_pitch_joint'])
    buffer.add(3010 * MS, ['head_pan_joint'], [0.9])       # stamped again
    assert buffer.at(3010 * MS, ['head_pan_joint']).unstamped == ()
