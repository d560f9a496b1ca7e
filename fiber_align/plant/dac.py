# SPDX-License-Identifier: Apache-2.0
"""
The drive a sample-clocked DAC latched at clock edges its simulation slept through.

A DAC clocked at the sample rate latches, at each clock edge, the last value written to
it before that edge, and the amplifier holds it for one period. A simulated plant whose
process stalled for ``n`` periods must advance over those periods afterwards; the values
written meanwhile (``writes``, in order) arrive only when it wakes, without their times.
Holding the newest of them for the whole stall, or the value before it, turns every ramp
the driver made meanwhile (its watchdog's ramp to the safe voltage, 2 V a period) into
one step, which rings the bending mode by the step's full height (a 52 V step: -20 um).
:func:`replay_edges` spreads the writes evenly over the stall instead: no write is
skipped while there are no more writes than edges, so the plant sees the driver's ramp
as a ramp (slower than it was, never steeper) and ends at the newest value.
"""


def replay_edges(prev, writes, n):
    """
    Return the values (V) latched at the ``n`` edges of a stall, the last edge's last.

    The ``m`` writes are taken as evenly spaced over the ``n`` periods, the last one at
    the last edge: edge ``j`` (1..n) latches the ``floor(j m / n)``-th write, or ``prev``
    before the first. With ``m <= n`` consecutive edges latch consecutive writes or the
    same one, so none is skipped; with ``m > n`` some are (at most ``ceil(m / n) - 1``
    between two edges), as a DAC that is written faster than it is clocked skips them.

    :param prev: the value (V) latched at the edge before the stall.
    :param writes: the values (V) written since, oldest first.
    :param n: edges (periods) to fill, >= 1.
    :returns: a list of ``n`` values (V); the last is ``writes[-1]`` (``prev`` if none).
    """
    n = int(n)
    if n < 1:
        raise ValueError('n must be >= 1, got %d' % n)
    m = len(writes)
    out = []
    for j in range(1, n + 1):
        i = j * m // n
        out.append(writes[i - 1] if i else prev)
    return out


#: ticks the catch-up of a long stall waits, at most, for the drives written during it
MAX_WAIT_TICKS = 20


class DacClock:
    """
    The realtime simulated plant's sample clock: latch, late ticks, catch-up and replay.

    At tick k the plant advances over [t_k-1, t_k] with the drive latched at tick k-1,
    then latches the newest drive written since (zero-order hold: a tick without a new
    drive is a missed cycle). A tick that comes late advances the plant by every elapsed
    period (the plant keeps wall time), counts the skipped periods as missed and replays
    the drives written meanwhile over them (:func:`replay_edges`); after a stall of over
    ``max_catch_up`` periods it waits for them (they race the timer when the process
    wakes, and a loaded machine delivers a backlog over several ticks): one tick, then
    while new ones still arrive, at most :data:`MAX_WAIT_TICKS` ticks. Pure: the node
    passes the clock readings (s, ns).

    :param plant: the :class:`~fiber_align.plant.actuator.SimulatedActuator`.
    :param period_s: sample period (s).
    :param max_catch_up: the longest stall (periods) caught up at once.
    :param depth: most writes kept between two ticks.
    """

    def __init__(self, plant, period_s, max_catch_up, depth):
        """Start held at sample 0 with 0 V latched."""
        self.plant = plant
        self.period_s = float(period_s)
        self.period_ns = int(round(self.period_s * 1e9))
        self.max_catch_up = int(max_catch_up)
        self.depth = int(depth)
        self.u_latched = 0.0            # drive held over the present period (V)
        self.v_latest = 0.0             # newest drive written (V)
        self.writes = []                # drives written since the last tick (V)
        self.drives_in_period = 0
        self.n_drive = 0
        self.waited = 0                 # ticks a stall's catch-up has waited
        self.n_drive_waited = 0         # drives written when it last waited
        self.m0 = None                  # scheduled time (s) of tick 0; None: restart
        self.wall0_ns = 0               # system time (ns) of the nominal tick 0
        self.stats_from = 0             # first sample counted in the statistics
        self.missed = 0                 # ticks without a new drive
        self.skipped = 0                # periods skipped by late ticks
        #: the driver holds its output (inactive, disabled, tripped): the loop is not
        #: meant to run, a tick without a drive is idle, neither counted nor missed
        self.held = False
        self.idle = 0                   # ticks while held

    def write(self, v):
        """Take a drive (V) written to the DAC."""
        self.v_latest = v
        self.n_drive += 1
        self.drives_in_period += 1
        if len(self.writes) < self.depth:
            self.writes.append(v)

    def tick(self, k, now, sched, wall_ns, fresh):
        """
        Run one tick; return the periods the clock advanced, or ``None`` (wait a tick).

        :param k: index of the last published sample.
        :param now: the monotonic time (s) of this call; :param sched: this tick's
            scheduled time on that clock (s); :param wall_ns: the system time now (ns).
        :param fresh: no sample published yet (sample 0 is the plant at rest).
        """
        period = self.period_s
        if self.m0 is None:             # first tick after a start: sample 0 or the next
            k_next = k + (0 if fresh else 1)
            self.m0 = sched - k_next * period
            self.wall0_ns = wall_ns - int(round((now - sched) * 1e9)) \
                - k_next * self.period_ns
        steps = 0
        if not fresh:
            steps = max(1, int(round((sched - self.m0) / period)) - k)
            if steps > self.max_catch_up and self._wait_for_drives():
                return None             # a stall: its drives may still be on their way
            self.waited = 0
            if k >= self.stats_from:
                # held: no drive is due, the period is idle; a late tick's periods are
                # the plant's own loss (a stall that made the driver trip too)
                if self.held:
                    self.idle += 1
                elif self.drives_in_period == 0 and self.n_drive > 0:
                    self.missed += 1
                self.skipped += steps - 1
            self.plant.step(self.u_latched)
            if steps > 1:
                for v in replay_edges(self.u_latched, self.writes, steps)[:-1]:
                    self.plant.step(v)
        self.writes.clear()
        # latch last: in a composed process the drive computed from the sample about to
        # be published arrives inside its publish (in-process delivery), for the next tick
        self.u_latched = self.v_latest
        self.drives_in_period = 0
        return steps

    def _wait_for_drives(self):
        """Return True while a long stall's catch-up waits (one tick, then while drives come)."""
        if self.waited == 0 or (self.n_drive > self.n_drive_waited
                                and self.waited < MAX_WAIT_TICKS):
            self.waited += 1
            self.n_drive_waited = self.n_drive
            return True
        return False
