import numpy as np
import pytest

from abp_belief import population


@pytest.fixture(scope='session')
def full7():
    return population.full_set(7)


@pytest.fixture(scope='session')
def robot():
    return population.robot_set(seed=0)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
