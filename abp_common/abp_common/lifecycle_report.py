"""What a managed node reports to the lifecycle manager, and when a graph is ready (no rclpy).

A node's report (`endpoint_report`) is a dict: its lifecycle `state` label, an
`instance` id (new in each process), `inputs` {topic: publishers matched by its
subscription on that topic (the fewest, if it has several)} and `outputs` {topic:
subscriptions matched by its publisher on that topic}. The matched counts come from
the node's own DDS endpoints, so they say what that process has discovered, not what
the manager has.

`unmatched(reports)` takes {node: report} of the managed nodes and lists every edge
between two of them that is not matched yet: for each topic that one managed node
publishes and another (or the same) subscribes to, each subscriber must have matched at
least as many publishers as there are managed publishers on it, and each publisher at
least as many subscriptions as there are managed subscribers. Topics outside the managed
graph (a robot driver's /joint_states, a client's goal) are not required.
"""

# Every node has these endpoints; they are no edge of the graph.
IGNORED_TOPICS = frozenset({'/parameter_events', '/rosout', '/diagnostics'})


def endpoint_report(state, instance, subscriptions, publishers):
    """The report of one node; `subscriptions` and `publishers` are (topic, matched)."""
    return {'state': state, 'instance': instance,
            'inputs': _fewest(subscriptions), 'outputs': _fewest(publishers)}


def _fewest(pairs):
    out = {}
    for topic, matched in pairs:
        if topic in IGNORED_TOPICS:
            continue
        out[topic] = min(int(matched), out.get(topic, int(matched)))
    return out


def unmatched(reports):
    """['<node>: <topic> matched i of n publishers', ...] for the edges not matched yet."""
    publishers, subscribers = {}, {}
    for node, report in reports.items():
        for topic in report.get('outputs', {}):
            publishers.setdefault(topic, []).append(node)
        for topic in report.get('inputs', {}):
            subscribers.setdefault(topic, []).append(node)
    missing = []
    for topic in sorted(set(publishers) & set(subscribers)):
        pubs, subs = publishers[topic], subscribers[topic]
        for node in subs:
            have = reports[node]['inputs'][topic]
            if have < len(pubs):
                missing.append(f'{node}: {topic} matched {have} of {len(pubs)} publishers '
                               f'({", ".join(pubs)})')
        for node in pubs:
            have = reports[node]['outputs'][topic]
            if have < len(subs):
                missing.append(f'{node}: {topic} matched {have} of {len(subs)} subscribers '
                               f'({", ".join(subs)})')
    return missing


def next_transition(state, instance, settled_instance):
    """The transition a manager asks of a node next: 'configure', 'activate' or None.

    A manager brings each node *instance* (one process) up once: when it has reached
    active, or refused a transition, it is settled and left alone (a node deactivated or
    cleaned up on purpose stays so, a node that failed to configure is not asked again
    in a loop). A respawned node is a new instance, so it is brought up again."""
    if instance is None or instance == settled_instance:
        return None
    return {'unconfigured': 'configure', 'inactive': 'activate'}.get(state)


def not_active(reports, node_names):
    """['<node> is <state>', ...] for the managed nodes that are not active (or silent)."""
    out = []
    for node in node_names:
        report = reports.get(node)
        if report is None:
            out.append(f'{node} does not answer')
        elif report.get('state') != 'active':
            out.append(f'{node} is {report.get("state")}')
    return out


__all__ = ['IGNORED_TOPICS', 'endpoint_report', 'next_transition', 'not_active', 'unmatched']
