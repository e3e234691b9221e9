"""System tests: no graph outlives the test that started it (tests/helpers/graph.py says
why that matters for the tests after it)."""

import pytest

from tests.helpers.graph import kill_leftovers


@pytest.fixture(autouse=True)
def no_graph_left_behind(request):
    yield
    left = kill_leftovers()
    report = getattr(request.node, 'abp_report_call', None)
    if left and report is not None and report.passed:
        pytest.fail('the test left graph processes running (now killed):\n' + '\n'.join(left))
