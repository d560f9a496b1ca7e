# SPDX-License-Identifier: Apache-2.0
"""
The periods a loop on a fixed grid of deadlines lost: the plant's rule, standard library only.

Apart from :mod:`~fiber_align.control.cycle` (numpy) so that the machine-floor probe
(:mod:`~fiber_align.control.floor_probe`) starts in tens of milliseconds: numpy's import
takes hundreds of milliseconds on a loaded machine and starts BLAS threads.
"""


class DeadlineGrid:
    """
    The periods a loop on a fixed grid of deadlines lost, counted as the plant counts them.

    A loop that sleeps to each deadline ``t0 + k period`` and wakes at ``now`` serves the
    deadline it slept for; the deadlines that passed meanwhile are lost, as rcl's timer
    skips the calls a late callback missed and the realtime plant counts them
    (``missed_late_tick``). Pure: the caller passes the clock readings (s, monotonic).
    The stalls (wake-ups that lost at least one period) are kept, oldest first, up to
    ``keep`` of them; the totals count every one.

    :param period_s: the loop's period (s).
    :param t0_s: the time (s) the grid starts at; the first deadline is one period later.
    """

    def __init__(self, period_s, t0_s, keep=100000):
        """Start at ``t0_s`` with nothing lost."""
        self.period_s = float(period_s)
        self.t0_s = float(t0_s)
        self.deadline = self.t0_s + self.period_s
        self.ticks = 0              # wake-ups
        self.lost = 0               # deadlines passed unserved
        self.stalls = []            # (wake-up time s, periods lost)
        self.keep = int(keep)

    def wake(self, now):
        """Count a wake-up at ``now`` (s); return the next deadline (s)."""
        lost = int((now - self.deadline) // self.period_s) if now > self.deadline else 0
        self.ticks += 1
        if lost > 0:
            self.lost += lost
            if len(self.stalls) < self.keep:
                self.stalls.append((now, lost))
        self.deadline += (lost + 1) * self.period_s
        return self.deadline

    def figures(self, now):
        """
        Return the loop's figures up to ``now`` (s).

        :returns: dict: ``periods`` (deadlines since the start), ``lost``, ``lost_share``
            (1), ``stalls`` (wake-ups that lost a period), ``worst_stall_s`` (the longest
            wait past a deadline, s, to one period), ``seconds``.
        """
        periods = max(0, int((float(now) - self.t0_s) // self.period_s))
        worst = max((n for _, n in self.stalls), default=0)
        return {'periods': periods, 'lost': self.lost,
                'lost_share': self.lost / periods if periods else 0.0,
                'stalls': len(self.stalls), 'worst_stall_s': (worst + 1) * self.period_s
                if worst else 0.0, 'seconds': float(now) - self.t0_s}
