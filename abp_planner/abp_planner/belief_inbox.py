"""The planner's inbox of beliefs from the belief node (plain Python, no rclpy).

The belief node's messages arrive in order, one at a time (the node's exclusive callback
group for /abp/belief). The inbox keeps the latest one, for the episode to wait on:

- After `reset_asked()`, everything up to the reset's own belief (step 0) is from before
  the reset (latched, or in flight) and is not this episode's: it is skipped.
- A belief whose step goes back without a reset having been asked for comes from a new
  belief node (a respawn before DDS saw the old node gone): its belief lacks the
  episode's evidence. The inbox remembers that (`take_restart()`), however quickly the new
  node's steps then climb past the step the episode waits for: the waiter sees only the
  latest belief when it wakes, and a new node re-observing the cube can reach that step
  within a second (clean-clone run 67).
"""

import threading
import time


class BeliefInbox:
    def __init__(self):
        self._cond = threading.Condition()
        self._latest = None
        self._before_reset = False   # a reset was asked for; its belief (step 0) not yet in
        self._restarted = False      # a belief went back without a reset asked for

    def reset_asked(self):
        """A reset is about to be asked for: forget the last episode's belief."""
        with self._cond:
            self._before_reset = True
            self._restarted = False
            self._latest = None

    def reset_belief_refused(self):
        """The reset's own belief was refused (its stamp): the corrections after it are
        still this episode's, so they must not be skipped."""
        with self._cond:
            self._before_reset = False

    def offer(self, belief):
        """A belief from the topic (anything with a `step`); False when it is skipped as
        from before the reset."""
        with self._cond:
            if self._before_reset and belief.step != 0:
                return False
            if not self._before_reset and self._latest is not None \
                    and belief.step < self._latest.step:
                self._restarted = True
            self._before_reset = False
            self._latest = belief
            self._cond.notify_all()
            return True

    def latest(self):
        with self._cond:
            return self._latest

    def take_restart(self):
        """True once after a belief went back without a reset asked for."""
        with self._cond:
            restarted, self._restarted = self._restarted, False
            return restarted

    def wait(self, predicate, timeout_s, still_running=lambda: True):
        """The latest belief once `predicate(belief)` holds, or once the belief node is
        seen to have restarted (the caller asks `take_restart()`), or None after
        `timeout_s` (or when `still_running()` turns false)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._before_reset or self._latest is None \
                    or not (self._restarted or predicate(self._latest)):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not still_running():
                    return None
                self._cond.wait(min(remaining, 0.1))
            return self._latest


__all__ = ['BeliefInbox']
