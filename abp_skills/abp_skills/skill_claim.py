"""One skill at a time, across processes: the claim every skills node holds while a goal
runs (plain code, no rclpy).

Every skills node publishes its state on a latched topic (abp_common.names.SKILLS_ACTIVE,
JSON `{"node", "skill", "since", "goal"}`, `skill` empty when idle) and reads the others'.
`SkillClaim.claim(skill)` grants a goal when no skill runs in this process (a local lock)
nor in a live peer; it then announces the claim. When other nodes publish on the topic,
it waits `settle_s` for a simultaneous claim and, if a peer claimed earlier (by `since`,
ties broken by node name), gives way. The ROS side injects `publish(text)`, the graph's
`publishers()` (fully qualified names of the nodes publishing the topic, one per
publisher) and feeds `on_message(text)`; `wall_clock`, `sleep`, `monotonic` and
`new_goal_id` are injected too, so the rule is unit-tested without DDS.

A peer whose state arrived is forgotten only when the graph shows it gone: it was listed
among the publishers and no longer is, or it was never listed within `unlisted_grace_s`
wall seconds of its last message. The graph lags the data: a peer's message can arrive
before this process's graph lists the peer under its name (rmw learns node names from
another topic), and a busy claim dropped then would let a second skill run.
`on_message` returns the peer's state when it changed, so that the node can say so: a
test waits for that line instead of guessing how long the claim takes to travel.
"""

import json
import threading
import time
import uuid

# Wall seconds a peer's state is trusted before the graph lists the peer: longer than the
# graph's lag behind the data on a loaded machine, short enough that a peer that died
# before it was ever listed does not block the skills for long.
UNLISTED_GRACE_S = 30.0


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
                 new_goal_id=lambda: uuid.uuid4().hex, monotonic=time.monotonic,
                 unlisted_grace_s=UNLISTED_GRACE_S):
        self.node = node                  # this node's fully qualified name
        self._publish = publish
        self._publishers = publishers
        self._wall_clock = wall_clock
        self._sleep = sleep
        self._new_goal_id = new_goal_id
        self._monotonic = monotonic
        self._unlisted_grace_s = float(unlisted_grace_s)
        self._run_lock = threading.Lock()    # held while a goal of this process runs
        self._peers_lock = threading.Lock()
        self._peers = {}                     # node -> its latest state
        self._heard_at = {}                  # node -> monotonic time of its latest state
        self._listed = set()                 # peers the graph has listed since they spoke
        self.active = None                   # {'skill', 'since', 'goal'} while running

    def announce(self):
        """Publish this node's state (at start-up, on a claim and on a release)."""
        self._publish(encode_state(self.node, self.active))

    def on_message(self, text):
        """A state message from the topic (this node's own are ignored). Returns the
        peer's state when it is new or changed (another skill or goal), else None."""
        state = decode_state(text)
        if state is None or state['node'] == self.node:
            return None
        node = state['node']
        with self._peers_lock:
            before = self._peers.get(node)
            self._peers[node] = state
            self._heard_at[node] = self._monotonic()
        key = ('skill', 'goal')
        if before is None or [before.get(k) for k in key] != [state.get(k) for k in key]:
            return dict(state)
        return None

    def busy_peers(self):
        """States of the live peers running a skill (peers whose process is gone are
        forgotten: see the module's doc)."""
        live = set(self._publishers())
        now = self._monotonic()
        with self._peers_lock:
            for node in list(self._peers):
                if node in live:
                    self._listed.add(node)
                elif (node in self._listed
                      or now - self._heard_at[node] > self._unlisted_grace_s):
                    del self._peers[node], self._heard_at[node]
                    self._listed.discard(node)
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


__all__ = ['UNLISTED_GRACE_S', 'SkillClaim', 'decode_state', 'encode_state']
