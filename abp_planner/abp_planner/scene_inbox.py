"""The planner's inbox of scene beliefs (/abp/beliefs, abp_msgs/SceneBelief) for the
multi-object episode (plain Python, no rclpy). `belief_inbox.BeliefInbox` does the same
for the one-object /abp/belief; here every object track has its own step:

- After `reset_asked(track_id)`, the scenes up to the reset's own one are from before the
  reset (latched, or in flight) and are skipped: for a reset of every track (empty id)
  the reset's scene has no object (the belief node forgets its tracks), for one track it
  holds that track at step 0.
- A scene in which a track known to the inbox has gone, or whose step went back, without
  a reset asked for, comes from a new belief node (a respawn, or the belief node's own
  restart on a clock that went back): its beliefs lack the episode's evidence. The inbox
  remembers that (`take_restart()`) however quickly the new node's steps climb again.
"""

import threading
import time


def track_steps(scene):
    """{track id: step} of a SceneBelief-like message."""
    return {entry.track_id: int(entry.belief.step) for entry in scene.objects}


class SceneInbox:
    def __init__(self):
        self._cond = threading.Condition()
        self._latest = None
        self._steps = {}
        self._before_reset = None   # None, or the track id whose reset is awaited ('' = all)
        self._restarted = False

    def reset_asked(self, track_id=''):
        """A reset of `track_id` ('' = every track) is about to be asked for."""
        with self._cond:
            self._before_reset = track_id
            self._restarted = False
            self._latest = None
            self._steps = {}

    def reset_refused(self):
        """The reset was refused (or its scene will not come): take scenes as they come."""
        with self._cond:
            self._before_reset = None

    def _is_reset_scene(self, steps):
        if self._before_reset == '':
            return not steps
        return steps.get(self._before_reset) == 0

    def offer(self, scene):
        """A scene from the topic; False when it is skipped as from before the reset."""
        steps = track_steps(scene)
        with self._cond:
            if self._before_reset is not None:
                if not self._is_reset_scene(steps):
                    return False
                self._before_reset = None
            elif any(steps.get(track, -1) < step for track, step in self._steps.items()):
                self._restarted = True
            self._latest = scene
            self._steps = steps
            self._cond.notify_all()
            return True

    def latest(self):
        with self._cond:
            return self._latest

    def take_restart(self):
        """True once after a scene in which a track went back or vanished unasked."""
        with self._cond:
            restarted, self._restarted = self._restarted, False
            return restarted

    def wait(self, predicate, timeout_s, still_running=lambda: True):
        """The latest scene once `predicate(scene)` holds or a restart was seen (the
        caller asks `take_restart()`); None after `timeout_s` or once `still_running()`
        turns false."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._before_reset is not None or self._latest is None \
                    or not (self._restarted or predicate(self._latest)):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not still_running():
                    return None
                self._cond.wait(min(remaining, 0.1))
            return self._latest




class ScenePorts:
    """The planner's EpisodePorts (`ports`) with the scene belief (/abp/beliefs, `scenes`,
    a SceneInbox) where the one-object episode reads /abp/belief (`beliefs`, its
    BeliefInbox): scene_episode's ports. `running()`: False once the process stops."""

    def __init__(self, ports, scenes, beliefs, running):
        self._ports, self._scenes, self._beliefs, self._running = \
            ports, scenes, beliefs, running

    def __getattr__(self, name):
        return getattr(self._ports, name)

    def wait_for_belief(self, predicate, timeout_s):
        return self._scenes.wait(predicate, timeout_s, self._running)

    def latest_belief(self):
        return self._scenes.latest()

    def belief_restarted(self):
        # /abp/belief's step goes back whenever another object is updated: not a restart.
        self._beliefs.take_restart()
        return self._scenes.take_restart()


__all__ = ['SceneInbox', 'ScenePorts', 'track_steps']
