"""The planner's belief inbox (abp_planner.belief_inbox): what is this episode's belief,
and when the belief node has restarted, without ROS."""

import threading
from types import SimpleNamespace

from abp_planner.belief_inbox import BeliefInbox


def b(step):
    return SimpleNamespace(step=step)


def test_beliefs_from_before_the_reset_are_skipped_until_its_own_step_0():
    inbox = BeliefInbox()
    assert inbox.offer(b(7))
    inbox.reset_asked()
    assert inbox.latest() is None
    assert not inbox.offer(b(8))           # in flight from before the reset
    assert inbox.wait(lambda x: True, 0.05) is None
    assert inbox.offer(b(0)) and inbox.offer(b(1))
    assert inbox.wait(lambda x: x.step >= 1, 1.0).step == 1
    assert not inbox.take_restart()         # the reset was asked for: no restart


def test_a_step_that_goes_back_without_a_reset_is_a_new_belief_node():
    inbox = BeliefInbox()
    for step in range(6):
        inbox.offer(b(step))
    assert not inbox.take_restart()
    inbox.offer(b(0))                       # a respawned node starts again
    assert inbox.take_restart() and not inbox.take_restart()   # once


def test_a_waiter_that_wakes_after_the_new_node_passed_its_step_still_sees_the_restart():
    # Clean-clone run 67: the old node was at step 5 and the episode waited for step 7;
    # the respawned node's steps climbed 0, 1, ... 9 before the waiter woke. It saw step
    # 9, took it for the action's evidence and ended on a belief that had lost it.
    inbox = BeliefInbox()
    for step in range(6):
        inbox.offer(b(step))
    woke = threading.Event()
    seen = []

    def waiter():
        seen.append(inbox.wait(lambda x: x.step >= 7 or x.step < 5, 5.0))
        woke.set()
    # The waiter cannot look until the whole burst is in: the test holds the inbox's
    # (reentrant) lock while the new node's beliefs arrive.
    with inbox._cond:
        thread = threading.Thread(target=waiter)
        thread.start()
        for step in range(10):
            inbox.offer(b(step))
    thread.join(5.0)
    assert woke.is_set() and seen[0].step == 9
    assert inbox.take_restart(), 'the restart was lost in the burst'
