"""The sim bridge's timing rules without ROS or sleeps: pacing simulation time against an
injected wall clock, catching up, giving up when too far behind, the real-time-factor
report, and the camera and ground-truth schedules."""

import pytest

from abp_sim_bridge.sim_timing import (
    BaseCommandWait,
    CameraSchedule,
    GroundTruthSchedule,
    Pacer,
    StateSchedule,
    WallRateLimit,
    sim_seconds,
)

TICK_NS = 20_000_000  # 50 Hz
S = 1_000_000_000


class FakeClock:
    def __init__(self, t=100.0):
        self.t = t

    def __call__(self):
        return self.t


def drive(pacer, clock, sim_ns, wall_s, tick_cost_s=0.0, reports=None):
    """Run the simulation thread's loop for `wall_s` of fake wall time; each tick costs
    `tick_cost_s`. Returns the simulation time reached (ns)."""
    end = clock.t + wall_s
    while clock.t < end:
        wait = pacer.wait_s(sim_ns, sim_ns + TICK_NS)
        if wait > 0:
            clock.t += max(wait, 1e-6)  # a real clock moves on past rounding errors
            continue
        clock.t += tick_cost_s
        sim_ns += TICK_NS
        factor = pacer.ticked(sim_ns)
        if reports is not None and factor is not None:
            reports.append(factor)
    return sim_ns


@pytest.mark.parametrize('speedup', [0.5, 1.0, 4.0, 50.0])
def test_simulation_time_runs_at_the_speedup(speedup):
    clock = FakeClock()
    pacer = Pacer(speedup, 0, clock=clock)
    sim_ns = drive(pacer, clock, 0, 2.0)
    assert sim_ns * 1e-9 == pytest.approx(2.0 * speedup, abs=TICK_NS * 1e-9 + 1e-9)


def test_waits_are_what_is_left_to_the_next_tick_and_at_most_50_ms():
    clock = FakeClock()
    assert Pacer(4.0, 0, clock=clock).wait_s(0, TICK_NS) == pytest.approx(0.02 / 4)
    assert Pacer(0.1, 0, clock=clock).wait_s(0, TICK_NS) == pytest.approx(0.05)
    pacer = Pacer(1.0, 0, clock=clock)
    clock.t += 0.0201
    assert pacer.wait_s(0, TICK_NS) == 0.0  # due: tick now


def test_a_short_stall_is_caught_up_and_keeps_the_pace():
    clock = FakeClock()
    pacer = Pacer(1.0, 0, clock=clock)
    sim_ns = drive(pacer, clock, 0, 1.0)
    clock.t += 0.08  # the machine stalls for 80 ms (< 100 ms): catch up
    immediate = 0
    while pacer.wait_s(sim_ns, sim_ns + TICK_NS) == 0.0:
        sim_ns += TICK_NS
        immediate += 1
    assert immediate == 4
    sim_ns = drive(pacer, clock, sim_ns, 1.0)
    assert sim_ns * 1e-9 == pytest.approx(2.08, abs=0.021)  # no simulation time lost


def test_a_long_stall_lets_simulation_time_run_slower():
    clock = FakeClock()
    pacer = Pacer(1.0, 0, clock=clock)
    sim_ns = drive(pacer, clock, 0, 1.0)
    clock.t += 0.5  # too far behind (> 100 ms): re-anchor, do not race
    assert pacer.wait_s(sim_ns, sim_ns + TICK_NS) == 0.0
    sim_ns += TICK_NS
    assert pacer.wait_s(sim_ns, sim_ns + TICK_NS) > 0.0
    sim_ns = drive(pacer, clock, sim_ns, 1.0)
    assert sim_ns * 1e-9 == pytest.approx(2.0, abs=0.041)  # the stall is not made up


def test_a_new_speedup_applies_from_now():
    clock = FakeClock()
    pacer = Pacer(1.0, 0, clock=clock)
    sim_ns = drive(pacer, clock, 0, 1.0)
    pacer.set_speedup(10.0)
    assert pacer.speedup == 1.0  # applies at the next wait_s
    sim_ns = drive(pacer, clock, sim_ns, 1.0)
    assert pacer.speedup == 10.0
    assert sim_ns * 1e-9 == pytest.approx(11.0, abs=0.041)


def test_the_real_time_factor_is_reported_when_the_machine_cannot_keep_up():
    clock = FakeClock()
    reports = []
    # A tick costs 40 ms of wall time for 20 ms of simulation time: factor 0.5 at most.
    drive(Pacer(1.0, 0, clock=clock), clock, 0, 25.0, tick_cost_s=0.04, reports=reports)
    assert len(reports) == 2  # every 10 s
    assert all(f == pytest.approx(0.5, abs=0.01) for f in reports)
    on_pace = []
    drive(Pacer(1.0, 0, clock=clock), clock, 0, 25.0, tick_cost_s=0.001, reports=on_pace)
    assert on_pace == []


def test_camera_frames_at_whole_multiples_of_the_period():
    schedule = CameraSchedule(10.0, 0, TICK_NS)
    due = [t for t in range(TICK_NS, S + 1, TICK_NS) if schedule.due(t)]
    assert due == [k * S // 10 for k in range(1, 11)]
    # After a reset at 1.23 s: the next whole multiple after the first tick.
    assert CameraSchedule(10.0, 1_230_000_000, TICK_NS).next_ns == 1_300_000_000
    # Fallen behind: one frame, and the missed ones are skipped.
    late = CameraSchedule(10.0, 0, TICK_NS)
    assert late.due(350_000_000) and late.next_ns == 450_000_000
    assert not late.due(400_000_000)
    off = CameraSchedule(0.0, 0, TICK_NS)
    assert not any(off.due(t) for t in range(0, S, TICK_NS))


def test_ground_truth_at_once_then_periodic_and_after_every_event():
    schedule = GroundTruthSchedule(5.0, 0, TICK_NS)
    due = [t for t in range(TICK_NS, S + 1, TICK_NS) if schedule.due(t)]
    assert due[0] == TICK_NS and len(due) == 5  # the first tick, then every 200 ms
    assert all(b - a == 200_000_000 for a, b in zip(due[1:], due[2:]))
    assert schedule.due(S + TICK_NS, events=True)  # a contact event: at once
    only_events = GroundTruthSchedule(0.0, 0, TICK_NS)
    assert only_events.due(TICK_NS)  # first tick
    assert not any(only_events.due(t) for t in range(2 * TICK_NS, S, TICK_NS))
    assert only_events.due(S, events=True)


def test_command_stamps_in_simulation_seconds():
    assert sim_seconds(0, 5 * S) == 0.0  # zero stamp: on receipt
    assert sim_seconds(7 * S, 5 * S) == pytest.approx(2.0)
    assert sim_seconds(3 * S, 0) == pytest.approx(3.0)


def test_state_schedule_on_its_grid_and_at_every_forced_tick():
    tick = 20_000_000
    schedule = StateSchedule(25.0, 0, tick)
    due = [k * tick for k in range(1, 16) if schedule.due(k * tick, forced=(k % 5 == 0))]
    # 25 Hz grid (every 2nd tick) plus the camera ticks (every 5th).
    assert due == [k * tick for k in (2, 4, 5, 6, 8, 10, 12, 14, 15)]
    every_tick = StateSchedule(50.0, 0, tick)
    assert all(every_tick.due(k * tick) for k in range(1, 10))
    # A late tick publishes once and the grid goes on from there (no burst).
    late = StateSchedule(25.0, 0, tick)
    assert late.due(10 * tick) and not late.due(11 * tick) and late.due(12 * tick)


def test_wall_rate_limit():
    limit = WallRateLimit(20.0)
    assert limit.ready(0.0)
    limit.taken(0.0)
    assert not limit.ready(0.049) and limit.ready(0.05)
    unlimited = WallRateLimit(0.0)
    unlimited.taken(1.0)
    assert unlimited.ready(1.0)


def test_base_command_wait_holds_for_a_late_command_up_to_its_wall_bound():
    wait = BaseCommandWait(0.15, max_wall_s=0.5)
    ms = 1_000_000
    assert not wait.hold(100 * ms, (0.2, 0.0), 0, 0.0)           # on time
    assert wait.hold(150 * ms, (0.2, 0.0), 0, 1.0)               # late: wait
    assert wait.hold(150 * ms, (0.2, 0.0), 0, 1.4)
    assert not wait.hold(150 * ms, (0.2, 0.0), 0, 1.5)           # waited long enough
    assert wait.hold(400 * ms, (0.2, 0.0), 240 * ms, 2.0)        # the next late one
    assert wait.waits == 2
    assert not wait.hold(900 * ms, (0.0, 0.0), 0, 3.0)           # a stop: nothing to wait for
    assert not wait.hold(900 * ms, None, None, 3.0)
    assert not BaseCommandWait(0.0).hold(900 * ms, (0.2, 0.0), 0, 3.0)
