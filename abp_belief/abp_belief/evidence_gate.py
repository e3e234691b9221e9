"""Which observation corrects the belief, and when (plain Python, no rclpy).

Two rules of the belief node, kept here so they are tested without a ROS graph:

- Once per action: frames of one unchanged view are not independent evidence, so
  after a correction further observations wait for the next executed action (or a
  reset). With `once_per_action` off every observation corrects.
- Order across topics: observations and executed actions come on two topics whose
  relative order DDS does not keep. Frames taken before the last action ended show
  the old state and are dropped; frames stamped after it that arrive while no
  correction is due are held, in case the next action's message arrives after the
  frames that already show its outcome; that action then releases them, oldest first.

Times are the messages' own stamps (integer nanoseconds), so the gate needs no clock.
"""

import collections

# Deep enough that a replay or a busy machine does not overwrite unread inputs.
HELD_OBSERVATIONS = 100
# How far the clock may be behind the last action's end before it counts as having gone
# back: nodes take /clock at slightly different moments, by a few tens of ms.
CLOCK_JUMP_BACK_NS = 1_000_000_000


class EvidenceGate:
    """`offer` each observation, `corrected` after a correction, `action_executed` per
    executed action, `reset` with the belief. Observations are opaque items."""

    def __init__(self, once_per_action=True, max_held=HELD_OBSERVATIONS):
        self.once_per_action = bool(once_per_action)
        self._held = collections.deque(maxlen=max_held)
        self.dropped_stale = 0   # observations older than the last action, since the start
        self.reset()

    def reset(self):
        """A fresh episode: the next observation corrects, whatever its stamp."""
        self.awaiting_observation = True
        self.earliest_stamp_ns = 0
        self._held.clear()

    @property
    def held(self):
        """Number of observations waiting for the next action."""
        return len(self._held)

    def offer(self, stamp_ns, observation):
        """True: correct with `observation` now (then call `corrected` if it was used).
        False: it is stale (dropped) or not due (held for the next action)."""
        if stamp_ns < self.earliest_stamp_ns:
            self.dropped_stale += 1
            return False
        if self.once_per_action and not self.awaiting_observation:
            self._held.append((stamp_ns, observation))
            return False
        return True

    def clock_went_back(self, now_ns):
        """True when the clock `now_ns` is well before the last action's end: the time
        source started again (a restarted simulation, a bag played again), so every
        frame would be stale against a barrier the clock will not reach for as long as
        it had run, and the state the belief tracked is gone with that world."""
        return self.earliest_stamp_ns - now_ns > CLOCK_JUMP_BACK_NS

    def describe(self):
        """One line on what the gate does with the next observation (for diagnostics)."""
        if not self.once_per_action or self.awaiting_observation:
            return (f'the next observation stamped at or after '
                    f'{self.earliest_stamp_ns * 1e-9:.3f} s corrects')
        return f'this view was used; {self.held} observations held for the next action'

    def corrected(self):
        """The belief was corrected: the evidence of this view is used."""
        self.awaiting_observation = False

    def action_executed(self, stamp_ns, known=True):
        """An action ended at `stamp_ns`: older frames are stale from now on.

        Returns the held observations stamped at or after it, oldest first: the first
        frames of the new state, which overtook the action's message. Offer them to
        the filter in turn (after the prediction) until one corrects. An unknown
        action (`known` False) is not predicted: it releases nothing and leaves the
        once-per-action state as it was."""
        self.earliest_stamp_ns = stamp_ns
        early = sorted((held for held in self._held if held[0] >= stamp_ns),
                       key=lambda held: held[0])
        self._held.clear()
        if not known:
            return []
        self.awaiting_observation = True
        return [observation for _, observation in early]


__all__ = ['CLOCK_JUMP_BACK_NS', 'HELD_OBSERVATIONS', 'EvidenceGate']
