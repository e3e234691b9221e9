import pytest


@pytest.fixture(scope='session')
def full_models():
    from abp_belief import population
    return population.full_set(7)


@pytest.fixture(scope='session')
def full_matcher(full_models):
    from abp_perception.matcher import AspectMatcher
    return AspectMatcher(full_models)


@pytest.fixture(scope='session')
def scenes():
    from abp_bench.scenes import SceneGenerator
    return SceneGenerator(seed=7)


@pytest.fixture(scope='session')
def detector(scenes):
    from abp_perception.detector import TagDetector
    return TagDetector(scenes.K)
