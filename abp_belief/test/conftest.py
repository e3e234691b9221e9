import numpy as np
import pytest

from abp_belief import population
from abp_belief.modelset import TransitionParams


@pytest.fixture(scope='session')
def full7():
    return population.full_set(7)


@pytest.fixture(scope='session')
def robot():
    return population.robot_set(seed=0)


# The paper's hand-written table (docs/MODEL.md), for the tests of its physics.
@pytest.fixture(scope='session')
def full7_paper():
    return population.full_set(7, transition_params=TransitionParams(rules='paper'))


@pytest.fixture(scope='session')
def robot_paper():
    return population.robot_set(seed=0, transition_params=TransitionParams(rules='paper'))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
