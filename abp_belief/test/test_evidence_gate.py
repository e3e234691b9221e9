"""The belief node's gate without DDS: once per action, stale frames, overtaking frames."""

from abp_belief.evidence_gate import EvidenceGate


def s(seconds):
    return int(seconds * 1e9)


def test_first_observation_corrects_then_frames_of_the_same_view_wait():
    gate = EvidenceGate()
    assert gate.offer(s(1), 'a')
    gate.corrected()
    assert not gate.offer(s(2), 'b')  # same view: held, not new evidence
    assert gate.held == 1
    assert not gate.awaiting_observation


def test_failed_correction_leaves_the_gate_open():
    gate = EvidenceGate()
    assert gate.offer(s(1), 'bad')  # the filter refuses it: corrected() is not called
    assert gate.offer(s(2), 'good')


def test_every_observation_corrects_without_once_per_action():
    gate = EvidenceGate(once_per_action=False)
    for t in range(5):
        assert gate.offer(s(t), t)
        gate.corrected()
    assert gate.held == 0


def test_frames_older_than_the_last_action_are_stale():
    gate = EvidenceGate()
    assert gate.offer(s(1), 'a')
    gate.corrected()
    assert gate.action_executed(s(100)) == []
    assert gate.awaiting_observation
    assert not gate.offer(s(99), 'stale')
    assert gate.held == 0
    assert gate.offer(s(101), 'fresh')


def test_the_gate_describes_itself_and_counts_stale_frames():
    gate = EvidenceGate()
    assert gate.describe() == 'the next observation stamped at or after 0.000 s corrects'
    gate.offer(s(1), 'a')
    gate.corrected()
    gate.offer(s(2), 'b')
    assert gate.describe() == 'this view was used; 1 observations held for the next action'
    gate.action_executed(s(10))
    gate.offer(s(9), 'stale')
    assert gate.dropped_stale == 1
    assert gate.describe() == 'the next observation stamped at or after 10.000 s corrects'


def test_frames_that_overtake_their_action_are_released_oldest_first():
    gate = EvidenceGate()
    assert gate.offer(s(1), 'first')
    gate.corrected()
    # Frames of the old view, then two of the new state arriving before its action.
    assert not gate.offer(s(150), 'old view')
    assert not gate.offer(s(202), 'new b')
    assert not gate.offer(s(201), 'new a')
    released = gate.action_executed(s(200))
    assert released == ['new a', 'new b']
    assert gate.held == 0 and gate.awaiting_observation


def test_unknown_action_releases_nothing_but_moves_the_stale_limit():
    gate = EvidenceGate()
    assert gate.offer(s(1), 'first')
    gate.corrected()
    assert not gate.offer(s(201), 'held')
    assert gate.action_executed(s(200), known=False) == []
    assert gate.held == 0
    assert not gate.awaiting_observation  # still no correction due
    assert not gate.offer(s(199), 'stale')


def test_reset_opens_the_gate_for_any_stamp():
    gate = EvidenceGate()
    gate.action_executed(s(100))
    assert gate.offer(s(101), 'x')
    gate.corrected()
    gate.offer(s(102), 'held')
    gate.reset()
    assert gate.held == 0 and gate.awaiting_observation
    assert gate.offer(s(5), 'old clock')  # e.g. a replay restarted its stamps


def test_the_held_queue_is_bounded():
    gate = EvidenceGate(max_held=3)
    gate.offer(s(0), 'first')
    gate.corrected()
    for t in range(1, 10):
        gate.offer(s(t), t)
    assert gate.held == 3
    assert gate.action_executed(s(0)) == [7, 8, 9]


def test_a_clock_well_before_the_last_action_has_gone_back():
    gate = EvidenceGate()
    gate.action_executed(s(100))
    # Nodes take /clock at slightly different moments: a clock just behind is no jump.
    assert not gate.clock_went_back(s(99.5))
    assert not gate.clock_went_back(s(100.2))
    # A restarted simulation's clock starts again near 0.
    assert gate.clock_went_back(s(3))
    gate.reset()
    assert not gate.clock_went_back(s(3))
