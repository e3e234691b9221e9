"""The lifecycle manager's plain rules (abp_common.lifecycle_report): which transition a
node instance is asked for, which nodes are not active, which topic edges are unmatched."""

from abp_common.lifecycle_report import endpoint_report, next_transition, not_active, unmatched


def report(state='active', inputs=(), outputs=(), instance='1'):
    return endpoint_report(state, instance, inputs, outputs)


def test_a_new_instance_is_configured_then_activated_and_then_left_alone():
    assert next_transition('unconfigured', 'a', None) == 'configure'
    assert next_transition('inactive', 'a', None) == 'activate'
    assert next_transition('active', 'a', None) is None
    # Settled (brought up, or refused): never asked again, whatever its state now.
    assert next_transition('unconfigured', 'a', 'a') is None
    assert next_transition('inactive', 'a', 'a') is None
    # A respawned node is a new instance.
    assert next_transition('unconfigured', 'b', 'a') == 'configure'
    assert next_transition('finalized', 'b', 'a') is None
    assert next_transition('unconfigured', None, None) is None


def test_report_keeps_the_fewest_matches_per_topic_and_drops_the_common_topics():
    r = report(inputs=[('/a', 2), ('/a', 1), ('/parameter_events', 0)],
               outputs=[('/b', 3), ('/rosout', 0), ('/diagnostics', 0)])
    assert r['inputs'] == {'/a': 1} and r['outputs'] == {'/b': 3}


def test_not_active_names_silent_and_inactive_nodes():
    reports = {'belief': report('inactive'), 'planner': report('active')}
    assert not_active(reports, ['matcher', 'belief', 'planner']) == [
        'matcher does not answer', 'belief is inactive']


def test_an_edge_between_managed_nodes_must_be_matched_on_both_ends():
    reports = {'matcher': report(outputs=[('/obs', 2)]),
               'belief': report(inputs=[('/obs', 1)]),
               'planner': report(inputs=[('/obs', 0), ('/belief', 1)])}
    assert unmatched(reports) == [
        'planner: /obs matched 0 of 1 publishers (matcher)']
    reports['planner'] = report(inputs=[('/obs', 1)])
    assert unmatched(reports) == []
    reports['matcher'] = report(outputs=[('/obs', 1)])
    assert unmatched(reports) == ['matcher: /obs matched 1 of 2 subscribers (belief, planner)']


def test_topics_from_outside_the_managed_graph_are_not_required():
    # /joint_states comes from a robot driver: nobody managed publishes it.
    reports = {'detector': report(inputs=[('/joint_states', 0)], outputs=[('/tags', 0)])}
    assert unmatched(reports) == []


def test_a_node_that_publishes_and_subscribes_one_topic_matches_itself():
    reports = {'skills': report(inputs=[('/active', 1)], outputs=[('/active', 1)])}
    assert unmatched(reports) == []
    reports['other'] = report(inputs=[('/active', 2)], outputs=[('/active', 2)])
    reports['skills'] = report(inputs=[('/active', 1)], outputs=[('/active', 2)])
    assert unmatched(reports) == ['skills: /active matched 1 of 2 publishers (skills, other)']
