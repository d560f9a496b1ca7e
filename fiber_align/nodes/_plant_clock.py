# SPDX-License-Identifier: Apache-2.0
"""
The sample clock of ``simulated_actuator``: start, hold, the drive and both sync modes.

:class:`PlantClock` is a mixin of the node (its ``plant``, ``dac``, ``health``, counters
and timers): lockstep advances one sample per drive, realtime ticks on the steady wall
clock (:class:`fiber_align.plant.dac.DacClock`). SI units (s, V).
"""

import time

from fiber_align.control.cycle import LatencyHistogram, loop_summary
from fiber_align.nodes.ros.diagnostics import endpoint_node_name

#: Realtime: samples before the statistics start (1 s at 1 kHz).
WARMUP_SAMPLES = 1000


class PlantClock:
    """Start and hold, the drive, lockstep stepping and the realtime tick (mixin)."""

    # -- start / hold ---------------------------------------------------------------
    def _maybe_autostart(self):
        # realtime too waits to hear a driver: a restarted plant sampling before its drive
        # reader matched left the loop open and the controller wound up (100 V, 158 um)
        if self.autostart and not self.started and self.count_publishers(
                self.resolve_topic_name('drive_voltage')) > 0 and (
                self.sync_mode == 'realtime'
                or self.count_subscribers(self.pub_disp.topic_name) > 0) \
                and self._reader_ready():
            self._start()

    def _reader_ready(self):
        """
        Return True when ``start_after_reader`` (realtime) receives both ends of the loop.

        The per-sample topics are volatile in realtime (a late reader sees the present),
        so a recorder that must hold every sample is waited for; past ``start_wait_s``
        the clock starts anyway, with a WARN naming the reader.
        """
        name = self.start_reader
        if not name or self.sync_mode != 'realtime':
            return True
        topics = (self.pub_disp.topic_name, self.resolve_topic_name('drive_voltage'))
        # a bare name: the node in this plant's namespace; a full one (the station's
        # recorder, in the namespace above the axes) as it is
        full = name if name.startswith('/') else '%s/%s' % (
            self.get_namespace().rstrip('/'), name)
        if all(any(endpoint_node_name(i) == full
                   for i in self.get_subscriptions_info_by_topic(t)) for t in topics):
            return True
        if time.monotonic() - self.created < self.start_wait_s:
            return False
        why = ('%s did not subscribe to displacement and drive_voltage within %g s: the '
               'clock starts without it (it misses the first samples)'
               % (name, self.start_wait_s))
        self.get_logger().warn(why)
        self.health.warn(why)
        return True

    def _on_run(self, request, response):
        """Start (``data`` true) or hold (false) the sample clock."""
        if request.data:
            self._start()
        else:
            self.running, self.dac.m0 = False, None
            self.health.status(0, 'held at sample %d' % self.k)
        response.success, response.message = True, self.health.message
        return response

    def _start(self):
        if self.running:
            return
        self._autostart_timer.cancel()
        self.running = True
        self.health.status(0, 'running')
        if not self.started:
            self.started = True
            self.get_logger().info('sample clock started (%s)' % self.sync_mode)
            if self.sync_mode == 'lockstep':
                self.wait_since = time.monotonic()
                self._publish_sample(0.0)
        elif self.sync_mode == 'lockstep':
            self.wait_since = time.monotonic()
            self._next.trigger()

    # -- drive ----------------------------------------------------------------------
    def _on_drive(self, msg):
        """Take a drive command (V); realtime: keep the newest for the next tick."""
        if self.sync_mode == 'realtime':
            self.dac.write(msg.data)
            if not self.drive_seen:
                self.drive_seen = True
                lat = time.perf_counter() - self.t_pub
                self.health.cycle.record(lat, self.k)
                if self.k >= self.dac.stats_from:
                    self.lat.record(lat)
            return
        self.pending.append(msg.data)
        if self.running and not self._advancing:
            self._next.trigger()

    def _advance(self):
        """
        Lockstep: apply the drive of sample k, publish sample k + 1 (one per callback).

        Run by the executor through a guard condition, one sample per call: in a composed
        process the whole loop answers a sample inside ``_publish_sample`` (in-process
        delivery), and a source in the same process (the sequencer) answers every
        sample, so stepping in a loop here would never return to the executor, and no
        service call (``~/run``, ``align``) would ever be answered.
        """
        if self._advancing or not (self.pending and self.running):
            return
        self._advancing = True
        try:
            self.plant.step(self.pending.pop(0))
            self.k += 1
            self.wait_since = time.monotonic()
            self._publish_sample(self.k * self.period_s)
        finally:
            self._advancing = False
        if self.pending and self.running:
            self._next.trigger()

    def _on_watch(self):
        """Lockstep: warn (and keep holding) when the drive is late."""
        self._update_values()
        if not (self.running and self.started) or self.wait_since is None:
            return
        late = time.monotonic() - self.wait_since
        if late > self.timeout_s:
            self.holds += 1
            msg = ('no drive_voltage for sample %d within %.3g s: holding'
                   % (self.k, self.timeout_s))
            self.get_logger().warn(msg)
            self.health.warn(msg)
            self.wait_since = time.monotonic()

    def _on_tick(self):
        """Realtime: one tick of the sample clock (:class:`DacClock`); True while it runs."""
        if not self.running:
            self.dac.writes.clear()
            return False
        until = self.timer.time_until_next_call()
        now = time.perf_counter()
        # scheduled time of this tick: the timer's next call minus one period
        sched = now + (until * 1e-9 if until is not None else 0.0) - self.period_s
        steps = self.dac.tick(self.k, now, sched, time.time_ns(), self.n_disp == 0)
        if steps is None:
            return True
        self.k += steps
        self.drive_seen = False
        self.t_pub = time.perf_counter()
        self._publish_sample(0.0)
        return True

    def reset_stats(self, warmup=WARMUP_SAMPLES):
        """Restart the realtime statistics ``warmup`` samples from now (0: at once)."""
        self.dac.stats_from = self.k + int(warmup)
        self.lat = LatencyHistogram()
        self.dac.missed = self.dac.skipped = 0

    def latency_stats(self):
        """Return the realtime loop statistics since :meth:`reset_stats` (loop_summary)."""
        dac = self.dac
        return loop_summary(self.lat, max(0, self.k - dac.stats_from), dac.missed,
                            dac.skipped, self.k + 1 if self.started else 0)
