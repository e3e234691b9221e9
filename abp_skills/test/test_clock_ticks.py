"""ClockTicks: the skills' control loops wake when ROS time moves (each /clock message
under use_sim_time), through rclpy's real clock and time source, not on a wall poll."""

import threading

import pytest

rclpy = pytest.importorskip('rclpy')

from builtin_interfaces.msg import Time  # noqa: E402
from rclpy.clock import ROSClock  # noqa: E402
from rclpy.time_source import TimeSource  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402

from abp_skills.clock_ticks import ClockTicks  # noqa: E402
from abp_skills.skill_checks import sleep_on_clock  # noqa: E402

LONG_S = 60.0   # a wake-up that does not come fails the test long before this


@pytest.fixture
def sim_clock():
    """A ROS clock on simulated time, moved by /clock messages given to its time source."""
    clock = ROSClock()
    source = TimeSource()
    source.attach_clock(clock)
    source.ros_time_is_active = True

    def tick(seconds):
        source.clock_callback(Clock(clock=Time(sec=int(seconds),
                                               nanosec=int(round(seconds % 1 * 1e9)))))
    tick(1.0)
    return clock, tick


def test_a_sleeper_wakes_when_the_clock_moves(sim_clock):
    clock, tick = sim_clock
    ticks = ClockTicks(clock)
    started, woke = threading.Event(), threading.Event()

    def sleeper():
        started.set()
        ticks.sleep(LONG_S)
        woke.set()
    thread = threading.Thread(target=sleeper, daemon=True)
    thread.start()
    started.wait(LONG_S)
    # The sleeper may not be waiting yet when the first tick comes: tick until it wakes.
    t = 1.0
    while not woke.wait(0.05):
        t += 0.02
        tick(t)
        assert t < 100.0, 'the sleeper did not wake when the clock moved'
    thread.join(LONG_S)
    assert not thread.is_alive()
    ticks.close()


def test_sleep_on_clock_ends_when_the_clock_reaches_the_period(sim_clock):
    clock, tick = sim_clock
    ticks = ClockTicks(clock)

    def now():
        return clock.now().nanoseconds * 1e-9
    done = threading.Event()
    # A long period in wall terms (its wall cap is 5 x 10 s): only the clock can end it.
    thread = threading.Thread(target=lambda: (sleep_on_clock(10.0, now, sleep=ticks.sleep),
                                              done.set()), daemon=True)
    thread.start()
    t = 1.0
    while not done.wait(0.01):
        t += 0.5
        tick(t)
        assert t < 1000.0, 'the sleep did not end when the clock passed its end'
    assert now() >= 11.0
    ticks.close()


def test_a_sleep_without_clock_ticks_ends_at_its_timeout():
    ticks = ClockTicks(ROSClock())   # ROS time inactive: system time never jumps
    ticks.sleep(0.01)
    ticks.sleep(0.0)
    ticks.close()
    ticks.close()   # closing twice is harmless
