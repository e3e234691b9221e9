"""One skill at a time, across processes: the claim every skills node holds while a goal
runs (plain code, no rclpy).

Every skills node publishes its state on a latched topic (abp_common.names.SKILLS_ACTIVE,
JSON `{"node", "skill", "since", "goal"}`, `skill` empty when idle) and reads the others'.
`SkillClaim.claim(skill)` grants a goal when no skill runs in this process (a local lock)
nor in a live peer; it then announces the claim. When other nodes publish on the topic,
it waits `settle_s` for a simultaneous claim and, if a peer claimed earlier (by `since`,
ties broken by node name), gives way. The ROS side injects `publish(text)`, the graph's
`publishers()` (fully qualified names of the nodes publishing the topic, one per
publisher) and feeds `on_message(text)`; `wall_clock`, `sleep` and `new_goal_id` are
injected too, so the rule is unit-tested without DDS.
"""

import json
import threading
import time
import uuid


def encode_state(node, active):
    """The topic's JSON text for `node` running `active` ({'skill', 'since', 'goal'}) or
    idle (None)."""
    state = active or {}
    return json.dumps({'node': node, 'skill': state.get('skill', ''),
                       'since': state.get('since', 0.0), 'goal': state.get('goal', '')})


def decode_state(text):
    """{'node', 'skill', 'since', 'goal'} of a message, or None when it is not one."""
    try:
        state = json.loads(text)
        state['node'] = str(state['node'])
    except (ValueError, KeyError, TypeError):
        return None
    return state


class SkillClaim:
    def __init__(self, node, publish, publishers, wall_clock=time.time, sleep=time.sleep,
                 new_goal_id=lambda: uuid.uuid4().hex):
        self.node = node                  # this node's fully qualified name
        self._publish = publish
        self._publishers = publishers
        self._wall_clock = wall_clock
        self._sleep = sleep
        self._new_goal_id = new_goal_id
        self._run_lock = threading.Lock()    # held while a goal of this process runs
        self._peers_lock = threading.Lock()
        self._peers = {}                     # node -> its latest state
        self.active = None                   # {'skill', 'since', 'goal'} while running

    def announce(self):
        """Publish this node's state (at start-up, on a claim and on a release)."""
        self._publish(encode_state(self.node, self.active))

    def on_message(self, text):
        """A state message from the topic (this node's own are ignored)."""
        state = decode_state(text)
        if state is None or state['node'] == self.node:
            return
        with self._peers_lock:
            self._peers[state['node']] = state

    def busy_peers(self):
        """States of the live peers running a skill (peers whose process is gone are
        forgotten)."""
        live = set(self._publishers())
        with self._peers_lock:
            for node in [n for n in self._peers if n not in live]:
                del self._peers[node]
            return [dict(p) for p in self._peers.values() if p.get('skill')]

    def claim(self, skill, settle_s=0.0):
        """None when a goal of `skill` may run (the claim is then held until `release`),
        else the reason it may not ('rejected: busy: ...')."""
        if not self._run_lock.acquire(blocking=False):
            running = (self.active or {}).get('skill', 'another skill')
            return f'rejected: busy: {running} is running'
        busy = self.busy_peers()
        if busy:
            self._run_lock.release()
            return f'rejected: busy: {busy[0]["skill"]} is running ({busy[0]["node"]})'
        self.active = {'skill': skill, 'since': self._wall_clock(), 'goal': self._new_goal_id()}
        self.announce()
        if len(self._publishers()) > 1:
            self._sleep(settle_s)
            mine = (self.active['since'], self.node)
            for peer in self.busy_peers():
                if (float(peer.get('since', 0.0)), str(peer['node'])) < mine:
                    self.release()
                    return (f'rejected: busy: {peer["skill"]} started at the same time '
                            f'({peer["node"]})')
        return None

    def release(self):
        """End the held claim and announce this node idle."""
        self.active = None
        self.announce()
        self._run_lock.release()


__all__ = ['SkillClaim', 'decode_state', 'encode_state']
