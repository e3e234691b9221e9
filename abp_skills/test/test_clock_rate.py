import pytest

from abp_skills.clock_rate import ClockRate


def test_rate_is_one_until_the_samples_span_enough_wall_time():
    rate = ClockRate(min_span_s=0.5)
    assert rate.rate() == 1.0
    rate.feed(0.0, 0.0)
    rate.feed(0.2, 2.0)
    assert rate.rate() == 1.0
    rate.feed(0.6, 6.0)
    assert rate.rate() == pytest.approx(10.0)


def test_rate_follows_a_changing_speed_up_within_its_window():
    rate = ClockRate(window_s=2.0)
    clock = 0.0
    for tick in range(1, 41):   # 4 s at speed-up 10, then 4 s at speed-up 2
        clock += 1.0 if tick <= 20 else 0.2
        rate.feed(0.1 * tick, clock)
    assert rate.rate() == pytest.approx(2.0, rel=0.05)


def test_a_slow_clock_or_a_clock_that_goes_back():
    rate = ClockRate()
    rate.feed(0.0, 100.0)
    rate.feed(1.0, 100.5)           # slower than the wall: keep the robot's lead
    assert rate.rate() == 1.0
    rate.feed(2.0, 3.0)             # a restarted simulator
    rate.feed(3.0, 8.0)
    assert rate.rate() == pytest.approx(5.0)
    rate.feed(3.0, 9.0)             # no wall time passed: ignored
    assert rate.rate() == pytest.approx(5.0)
