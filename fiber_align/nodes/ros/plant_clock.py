# SPDX-License-Identifier: Apache-2.0
"""
The sample clock of ``simulated_actuator``: start, hold, the drive and both sync modes.

:class:`PlantClock` is composed into the node (it owns its part, as control_toolbox's
``PidROS`` owns a ``Pid``): the clock's state (running, the index ``k`` of the last
published sample, the lockstep drives not yet applied, the realtime
:class:`fiber_align.plant.dac.DacClock` and latency statistics) and its timers. The node
gives it the plant, its settings, its ``/diagnostics`` and ``publish(t_s)``, which
publishes sample ``k``. Lockstep advances one sample per drive; realtime ticks on the
steady wall clock. SI units (s, V).
"""

import time

from rclpy.clock import Clock, ClockType

from fiber_align.control.cycle import LatencyHistogram, loop_summary
from fiber_align.control.trajectory import MAX_CATCH_UP
from fiber_align.nodes.ros.bus import sample_timer
from fiber_align.nodes.ros.diagnostics import endpoint_node_name
from fiber_align.nodes.ros.qos import SAMPLE_DEPTH
from fiber_align.plant.dac import DacClock

#: Realtime: samples before the statistics start (1 s at 1 kHz).
WARMUP_SAMPLES = 1000


class PlantClock:
    """Start and hold, the drive, lockstep stepping and the realtime tick (composed)."""

    def __init__(self, node, plant, publish, health, bus, settings, values):
        """
        Build the clock of ``plant`` and start its timers on ``node``.

        :param publish: ``publish(t_s)`` publishes sample :attr:`k` (lockstep: at ``t_s``).
        :param health: the node's :class:`~fiber_align.nodes.ros.diagnostics.Health`.
        :param bus: the process's LocalBus or None (realtime: its shared sample timer).
        :param settings: ``sync_mode``, ``autostart``, ``start_after_reader``,
            ``start_wait_s`` (s), ``lockstep_timeout_s`` (s) and ``topics``: the node's
            resolved ``displacement`` and ``drive_voltage``.
        :param values: lockstep: called by the watch timer (the node's diagnostics values).
        """
        self.node, self.plant, self.publish, self.health = node, plant, publish, health
        self.realtime = settings['sync_mode'] == 'realtime'
        self.autostart, self.start_reader = settings['autostart'], settings['start_after_reader']
        self.start_wait_s = settings['start_wait_s']
        self.timeout_s = settings['lockstep_timeout_s']     # changes live (the node's)
        self.disp_topic, self.drive_topic = settings['topics']
        self.period_s, self.created = plant.period_s, time.monotonic()
        self.running = self.started = False
        self.k = 0                      # index of the last published sample
        self.samples = 0                # samples published
        self.pending = []               # lockstep: drives not yet applied
        self._advancing = False         # lockstep: _advance is on the stack (local bus)
        # lockstep only: the EventsExecutor of a realtime process has no guard conditions
        self._next = None if self.realtime else node.create_guard_condition(self._advance)
        self.wait_since, self.holds = None, 0
        # realtime: the sample clock (DacClock) and the latency (perf_counter s)
        self.dac = DacClock(plant, self.period_s, MAX_CATCH_UP, SAMPLE_DEPTH)
        self.t_pub, self.drive_seen = None, True
        self.lat = LatencyHistogram()   # realtime: sample-to-drive latencies (s)
        self.reset_stats()
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._values = values
        if self.realtime:
            self.timer = sample_timer(node, bus, self.period_s, self._on_tick, steady)
        else:
            self.timer = node.create_timer(min(0.1, self.timeout_s / 2), self._on_watch,
                                           clock=steady)
        self._autostart_timer = node.create_timer(0.05, self._maybe_autostart, clock=steady)

    # -- start / hold ---------------------------------------------------------------
    def _maybe_autostart(self):
        # realtime too waits to hear a driver: a restarted plant sampling before its drive
        # reader matched left the loop open and the controller wound up (100 V, 158 um)
        node = self.node
        if self.autostart and not self.started and node.count_publishers(
                self.drive_topic) > 0 and (self.realtime or node.count_subscribers(
                    self.disp_topic) > 0) and self._reader_ready():
            self._start()

    def _reader_ready(self):
        """
        Return True when ``start_after_reader`` (realtime) receives both ends of the loop.

        The per-sample topics are volatile in realtime (a late reader sees the present),
        so a recorder that must hold every sample is waited for; past ``start_wait_s``
        the clock starts anyway, with a WARN naming the reader.
        """
        name, node = self.start_reader, self.node
        if not name or not self.realtime:
            return True
        # a bare name: the node in this plant's namespace; a full one (the station's
        # recorder, in the namespace above the axes) as it is
        full = name if name.startswith('/') else '%s/%s' % (
            node.get_namespace().rstrip('/'), name)
        if all(any(endpoint_node_name(i) == full
                   for i in node.get_subscriptions_info_by_topic(t))
               for t in (self.disp_topic, self.drive_topic)):
            return True
        if time.monotonic() - self.created < self.start_wait_s:
            return False
        why = ('%s did not subscribe to displacement and drive_voltage within %g s: the '
               'clock starts without it (it misses the first samples)'
               % (name, self.start_wait_s))
        node.get_logger().warn(why)
        self.health.warn(why)
        return True

    def on_run(self, request, response):
        """Start (``data`` true) or hold (false) the sample clock (``~/run``)."""
        if request.data:
            self._start()
        else:
            self.running, self.dac.m0 = False, None
            self.health.summary(0, 'held at sample %d' % self.k)
        response.success, response.message = True, self.health.message
        return response

    def _start(self):
        if self.running:
            return
        self._autostart_timer.cancel()
        self.running = True
        self.health.summary(0, 'running')
        if not self.started:
            self.started = True
            self.node.get_logger().info('sample clock started (%s)' % (
                'realtime' if self.realtime else 'lockstep'))
            if not self.realtime:
                self.wait_since = time.monotonic()
                self._publish(0.0)
        elif not self.realtime:
            self.wait_since = time.monotonic()
            self._next.trigger()

    def _publish(self, t_s):
        self.publish(t_s)
        self.samples += 1

    # -- drive ----------------------------------------------------------------------
    def on_drive(self, msg):
        """Take a drive command (V); realtime: keep the newest for the next tick."""
        if self.realtime:
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
        process the whole loop answers a sample inside ``publish`` (in-process delivery),
        and a source in the same process (the sequencer) answers every sample, so
        stepping in a loop here would never return to the executor, and no service call
        (``~/run``, ``align``) would ever be answered.
        """
        if self._advancing or not (self.pending and self.running):
            return
        self._advancing = True
        try:
            self.plant.step(self.pending.pop(0))
            self.k += 1
            self.wait_since = time.monotonic()
            self._publish(self.k * self.period_s)
        finally:
            self._advancing = False
        if self.pending and self.running:
            self._next.trigger()

    def _on_watch(self):
        """Lockstep: warn (and keep holding) when the drive is late."""
        self._values()
        if not (self.running and self.started) or self.wait_since is None:
            return
        if time.monotonic() - self.wait_since > self.timeout_s:
            self.holds += 1
            msg = ('no drive_voltage for sample %d within %.3g s: holding'
                   % (self.k, self.timeout_s))
            self.node.get_logger().warn(msg)
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
        steps = self.dac.tick(self.k, now, sched, time.time_ns(), self.samples == 0)
        if steps is None:
            return True
        self.k += steps
        self.drive_seen = False
        self.t_pub = time.perf_counter()
        self._publish(0.0)
        return True

    def reset_stats(self, warmup=WARMUP_SAMPLES):
        """Restart the realtime statistics ``warmup`` samples from now (0: at once)."""
        self.dac.stats_from = self.k + int(warmup)
        self.lat = LatencyHistogram()
        self.dac.missed = self.dac.skipped = self.dac.idle = 0

    def latency_stats(self):
        """Return the realtime loop statistics since :meth:`reset_stats` (loop_summary)."""
        dac = self.dac
        return loop_summary(self.lat, max(0, self.k - dac.stats_from), dac.missed,
                            dac.skipped, self.k + 1 if self.started else 0, dac.idle)

    def on_held(self, msg):
        """Take the driver's ``drive_held`` (realtime: its periods are idle, not missed)."""
        self.dac.held = bool(msg.data)
