"""Joint positions at a given time, from the last seconds of /joint_states (plain Python,
no rclpy).

On a robot an image arrives 30-100 ms after its exposure while the head moves; the
camera pose must be the one at the image's stamp, not at the newest joint state. Each
joint keeps its own stamped samples (controllers may publish joints in separate messages
at separate rates), `duration_s` of them behind the newest stamp. `at(t)` interpolates
each asked joint linearly between the samples around t. A stamp within `tolerance_s`
beyond the first or last sample takes that sample (joint states at 100 Hz leave up to
10 ms between the newest one and an image stamped just after it); further out, `at`
raises `OutsideBuffer` saying by how much, rather than guess.

Joint states stamped 0 carry no time (hand-written publishers, some tests): they are
kept as "unstamped" positions, and `at` returns them, marked so, while the newest
message of a joint was unstamped. A stamp more than `duration_s` before the newest one
means the sender's clock restarted (a restarted simulation): the buffer starts again.
"""

import bisect
from dataclasses import dataclass


class OutsideBuffer(ValueError):
    """No joint state near enough to the asked time."""


@dataclass(frozen=True)
class Lookup:
    positions: dict          # joint name -> position at the asked time
    worst_gap_s: float       # largest distance of the asked time beyond a joint's samples
    unstamped: tuple = ()    # joints whose newest state was unstamped (taken as is)


class JointStateBuffer:
    def __init__(self, duration_s=2.0, tolerance_s=0.02):
        if duration_s <= 0 or tolerance_s < 0:
            raise ValueError('duration_s must be > 0 and tolerance_s >= 0')
        self.duration_ns = int(duration_s * 1e9)
        self.tolerance_ns = int(tolerance_s * 1e9)
        self.clear()

    def clear(self):
        self._times = {}         # name -> sorted stamps (ns)
        self._values = {}        # name -> positions at those stamps
        self._unstamped = {}     # name -> position of its newest message, when unstamped
        self.newest_ns = None

    def __len__(self):
        return sum(len(t) for t in self._times.values())

    def add(self, stamp_ns, names, positions):
        """One joint state message (stamp in ns; 0 = unstamped)."""
        stamp_ns = int(stamp_ns)
        if stamp_ns == 0:
            self._unstamped.update(zip(names, (float(p) for p in positions)))
            return
        if self.newest_ns is not None and stamp_ns < self.newest_ns - self.duration_ns:
            self.clear()                    # the sender's clock went back: start again
        if self.newest_ns is None or stamp_ns > self.newest_ns:
            self.newest_ns = stamp_ns
        oldest = self.newest_ns - self.duration_ns
        for name, position in zip(names, positions):
            self._unstamped.pop(name, None)
            times = self._times.setdefault(name, [])
            values = self._values.setdefault(name, [])
            if not times or stamp_ns > times[-1]:
                times.append(stamp_ns)
                values.append(float(position))
            else:                           # out of order (or a repeated stamp)
                i = bisect.bisect_left(times, stamp_ns)
                if i < len(times) and times[i] == stamp_ns:
                    values[i] = float(position)
                else:
                    times.insert(i, stamp_ns)
                    values.insert(i, float(position))
            # Keep one sample at or before the window's start, for interpolating there.
            cut = bisect.bisect_right(times, oldest) - 1
            if cut > 0:
                del times[:cut]
                del values[:cut]

    def newest_of(self, names):
        """The newest stamp that every stamped joint of `names` has reached (None when none
        of them is stamped)."""
        lasts = [self._times[n][-1] for n in names
                 if self._times.get(n) and n not in self._unstamped]
        return min(lasts) if lasts else None

    def span_ns(self, name):
        """(first, last) stamp buffered for a joint, or None."""
        times = self._times.get(name)
        return (times[0], times[-1]) if times else None

    def at(self, t_ns, names):
        """Lookup of `names` at time t_ns. Joints never seen are left out of positions;
        raises OutsideBuffer when t_ns is beyond a joint's samples by more than the
        tolerance."""
        t_ns = int(t_ns)
        positions, worst, unstamped = {}, 0, []
        for name in names:
            if name in self._unstamped:
                positions[name] = self._unstamped[name]
                unstamped.append(name)
                continue
            times = self._times.get(name)
            if not times:
                continue
            values = self._values[name]
            i = bisect.bisect_right(times, t_ns)
            if i == 0 or i == len(times):
                edge = 0 if i == 0 else -1
                gap = abs(t_ns - times[edge])
                if gap > self.tolerance_ns:
                    when = 'before the oldest' if i == 0 else 'after the newest'
                    raise OutsideBuffer(
                        f'stamp is {gap * 1e-9:.3f} s {when} {name} state buffered '
                        f'({(times[-1] - times[0]) * 1e-9:.2f} s of them, tolerance '
                        f'{self.tolerance_ns * 1e-9:.3f} s)')
                positions[name] = values[edge]
                worst = max(worst, gap)
                continue
            t0, t1 = times[i - 1], times[i]
            w = (t_ns - t0) / (t1 - t0) if t1 > t0 else 0.0
            positions[name] = values[i - 1] + w * (values[i] - values[i - 1])
        return Lookup(positions, worst * 1e-9, tuple(unstamped))


__all__ = ['JointStateBuffer', 'Lookup', 'OutsideBuffer']
