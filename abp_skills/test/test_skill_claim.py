"""One skill at a time across processes (skill_claim.SkillClaim), without DDS: the topic,
the graph and the clocks are stand-ins."""

import json

from abp_skills.skill_claim import SkillClaim, decode_state, encode_state

ME = '/skill_servers'
PEER = '/lift_server'


class Graph:
    """The skills-active topic: what each node published last, and who publishes."""

    def __init__(self, publishers=(ME,)):
        self.publishers = list(publishers)
        self.sent = []

    def make(self, node=ME, wall=100.0, during_settle=None):
        def sleep(seconds):
            self.slept = seconds
            if during_settle is not None:
                during_settle()
        self.slept = None
        self.monotonic = 0.0
        return SkillClaim(node, lambda text: self.sent.append(json.loads(text)),
                          lambda: list(self.publishers), wall_clock=lambda: wall,
                          sleep=sleep, new_goal_id=lambda: 'goal-1',
                          monotonic=lambda: self.monotonic, unlisted_grace_s=30.0)


def peer_state(skill='lift', since=50.0, node=PEER):
    return encode_state(node, {'skill': skill, 'since': since, 'goal': 'g'} if skill else None)


def test_a_free_claim_is_held_and_announced_until_released():
    graph = Graph()
    claim = graph.make()
    assert claim.claim('orbit', settle_s=0.2) is None
    assert graph.sent[-1] == {'node': ME, 'skill': 'orbit', 'since': 100.0, 'goal': 'goal-1'}
    assert graph.slept is None          # alone on the topic: no settling wait
    assert claim.claim('push') == 'rejected: busy: orbit is running'
    claim.release()
    assert graph.sent[-1] == {'node': ME, 'skill': '', 'since': 0.0, 'goal': ''}
    assert claim.claim('push') is None


def test_a_live_busy_peer_rejects_the_goal_and_a_gone_one_does_not():
    graph = Graph(publishers=(ME, PEER))
    claim = graph.make()
    claim.on_message(peer_state('lift'))
    assert claim.claim('orbit') == f'rejected: busy: lift is running ({PEER})'
    assert graph.sent == []             # nothing announced, and the lock was given back
    graph.publishers = [ME]             # the lift process is gone
    assert claim.claim('orbit') is None


def test_a_busy_peer_the_graph_does_not_list_yet_still_rejects_the_goal():
    # The claim arrived before this process's graph knew the peer's name (the graph
    # lags the data): the claim holds, until the graph has had ample time to list it.
    graph = Graph(publishers=(ME, '_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_'))
    claim = graph.make()
    claim.on_message(peer_state('lift'))
    graph.monotonic = 29.0
    assert claim.claim('orbit') == f'rejected: busy: lift is running ({PEER})'
    graph.publishers = [ME, PEER]       # listed now: held for as long as it stays listed
    graph.monotonic = 100.0
    assert claim.claim('orbit') == f'rejected: busy: lift is running ({PEER})'
    graph.publishers = [ME]             # and forgotten once the graph shows it gone
    assert claim.claim('orbit') is None


def test_a_peer_never_listed_is_forgotten_after_the_grace():
    graph = Graph(publishers=(ME,))
    claim = graph.make()
    claim.on_message(peer_state('lift'))   # the peer died before the graph listed it
    graph.monotonic = 30.5
    assert claim.claim('orbit') is None


def test_a_message_reports_a_changed_peer_state_only():
    claim = Graph(publishers=(ME, PEER)).make()
    assert claim.on_message(peer_state(skill=''))['skill'] == ''
    assert claim.on_message(peer_state(skill='')) is None        # the same again
    assert claim.on_message(peer_state('lift'))['skill'] == 'lift'
    assert claim.on_message(peer_state('lift')) is None
    assert claim.on_message(peer_state(skill=''))['skill'] == ''
    assert claim.on_message(encode_state(ME, None)) is None      # its own
    assert claim.on_message('not json') is None


def test_idle_peers_and_own_or_malformed_messages_do_not_block():
    graph = Graph(publishers=(ME, PEER))
    claim = graph.make()
    claim.on_message(peer_state(skill=''))
    claim.on_message(encode_state(ME, {'skill': 'flip', 'since': 1.0, 'goal': 'x'}))
    claim.on_message('not json')
    claim.on_message(json.dumps({'skill': 'push'}))
    assert claim.busy_peers() == []
    assert claim.claim('orbit', settle_s=0.2) is None
    assert graph.slept == 0.2           # another publisher: wait for a simultaneous claim


def test_of_two_simultaneous_claims_the_earlier_wins():
    graph = Graph(publishers=(ME, PEER))
    later = graph.make(wall=100.0, during_settle=lambda: later.on_message(
        peer_state('lift', since=99.9)))
    assert later.claim('orbit', settle_s=0.2) == (
        f'rejected: busy: lift started at the same time ({PEER})')
    assert graph.sent[-1]['skill'] == ''   # gave way and announced itself idle
    assert later.active is None

    graph = Graph(publishers=(ME, PEER))
    earlier = graph.make(wall=100.0, during_settle=lambda: earlier.on_message(
        peer_state('lift', since=100.1)))
    assert earlier.claim('orbit', settle_s=0.2) is None
    assert earlier.active['skill'] == 'orbit'


def test_a_tie_is_broken_by_node_name():
    graph = Graph(publishers=('/a_server', '/b_server'))
    b = graph.make(node='/b_server', during_settle=lambda: b.on_message(
        peer_state('lift', since=100.0, node='/a_server')))
    assert b.claim('orbit').startswith('rejected: busy: lift started at the same time')
    graph = Graph(publishers=('/a_server', '/b_server'))
    a = graph.make(node='/a_server', during_settle=lambda: a.on_message(
        peer_state('lift', since=100.0, node='/b_server')))
    assert a.claim('orbit') is None


def test_state_text_round_trip():
    text = encode_state('/n', {'skill': 'push', 'since': 3.5, 'goal': 'abc'})
    assert decode_state(text) == {'node': '/n', 'skill': 'push', 'since': 3.5, 'goal': 'abc'}
    assert decode_state('[1, 2]') is None and decode_state('{}') is None
