# SPDX-License-Identifier: Apache-2.0
"""
``simulated_actuator``: the plant and sensor of the control core as a ROS 2 node.

Wraps :class:`fiber_align.plant.actuator.SimulatedActuator` (one ``step(v)`` = one control
period). Topics (relative names, SI units):

- sub ``drive_voltage`` (std_msgs/Float64, V): the amplifier input, held for one period
  (QoS: reliable in lockstep, best effort in realtime; deep in both).
- pub ``displacement`` (sensor_msgs/JointState, joint ``bimorph_tip``): position = the
  sensor reading (m), velocity = the model's tip velocity (m/s); header stamp = the sample
  time t_k (sim time in lockstep, wall time in realtime).
- pub ``optical_power`` (std_msgs/Float64, W): coupled power at the detector, when the
  optics model (:mod:`fiber_align.plant.optics`) is installed.
- pub ``/clock`` (rosgraph_msgs/Clock) in lockstep mode.
- srv ``~/run`` (std_srvs/SetBool): start (true) or hold (false) the sample clock; a held
  plant is frozen (realtime: the clock restarts on the next run).

Modes (parameter ``sync_mode``):

- ``lockstep`` publishes sample k with ``/clock`` = k T and advances to k + 1 only when
  the drive for sample k has arrived; if it does not arrive within ``lockstep_timeout_s``
  (wall time) it warns and keeps holding. The drive computed from y_k is applied over
  [t_k, t_k+1]: exactly the offline loop of docs/CONTRACTS.md.
- ``realtime`` runs a sample clock on the steady wall clock at ``rate_hz``, like a DAC and
  an ADC clocked by one sample clock. At tick k (time t_k) the node

  1. advances the plant over [t_k-1, t_k] with the drive latched at tick k-1 and
     publishes the measurement y_k (stamp: the nominal time t_k = t_0 + k T on the
     system clock, so stamps count sample periods exactly);
  2. latches the newest drive received since then; it is held over [t_k, t_k+1].

  The command computed from y_k arrives some 0.1-1 ms after t_k, is latched at t_k+1
  and first shows in y_k+2: the realtime loop has exactly **one period more delay than
  lockstep**, whatever the message latency is, as long as it is below one period. The
  controller accounts for this delay (``fuzzy_pid_controller``). A tick at which no drive
  has arrived since the previous tick is a **missed cycle**: the previous drive is held
  again (zero-order hold). A tick that comes more than one period late advances the plant
  by every elapsed period (the simulated plant keeps wall time) and counts the periods
  it skipped as missed too, replaying the drives written meanwhile over them
  (:mod:`fiber_align.plant.dac`: why); after a stall of over ``MAX_CATCH_UP`` periods
  it waits one tick for them (they race the timer when the process wakes).

Realtime: the sample-to-drive latency (publishing y_k to the first drive after it) and
the missed cycles, per run (:meth:`SimulatedActuatorNode.latency_stats`, ``latency_*``)
and per diagnostics window (``cycle.*``, :mod:`fiber_align.nodes._cycle`).
"""

import sys
import time

from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool

from fiber_align.nodes import _common as c
from fiber_align.nodes._cycle import CycleStats, LatencyHistogram, loop_summary
from fiber_align.plant.actuator import KINDS, SimulatedActuator
from fiber_align.plant.dac import replay_edges
from fiber_align.plant.optics import OpticalLink

NODE_NAME = 'simulated_actuator'
AREA_FILES = ('plant.yaml', 'optics.yaml')
JOINT_NAME = 'bimorph_tip'
#: Topics this node publishes (relative names; see ``_common.LocalBus``).
PUBLISHES = ('displacement', 'optical_power')
PLANT_KEYS = ('rate_hz', 'hysteresis', 'omega_n_rad_s', 'damping_ratio', 'v_min', 'v_max',
              'slew_rate_v_per_s', 'noise_rms_m', 'resolution_m', 'seed')
WARMUP_SAMPLES = 1000      # realtime: samples before the statistics start (1 s at 1 kHz)


class SimulatedActuatorNode(Node):
    """Transport, parameters and health around :class:`SimulatedActuator`."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare the parameters (defaults from config/), build the plant, wire topics.

        :param bus: the :class:`~fiber_align.nodes._common.LocalBus` of a composed
            process (``control_graph``), or ``None``.
        """
        super().__init__(NODE_NAME, **kwargs)
        d = c.node_defaults(NODE_NAME, AREA_FILES)
        ro = True
        self.rate_hz = c.declare(self, d, 'rate_hz', 'control rate (Hz)', 1.0, 20000.0, ro)
        c.declare(self, d, 'hysteresis', 'true hysteresis law of the plant', read_only=ro,
                  choices=KINDS)
        for name, text, lo, hi in (
                ('omega_n_rad_s', 'first bending mode (rad/s); <= 0: design model', -1.0, 1e6),
                ('damping_ratio', 'modal damping ratio (1)', 0.0, 0.999),
                ('v_min', 'amplifier lower limit (V)', -200.0, 200.0),
                ('v_max', 'amplifier upper limit (V)', -200.0, 200.0),
                ('slew_rate_v_per_s', 'amplifier slew limit (V/s); <= 0: none', -1.0, 1e12),
                ('noise_rms_m', 'sensor noise (m RMS)', 0.0, 1e-3),
                ('resolution_m', 'sensor resolution (m)', 0.0, 1e-3),
                ('seed', 'sensor noise seed', 0, 2 ** 31 - 1)):
            c.declare(self, d, name, text, lo, hi, ro)
        self.sync_mode = c.declare(self, d, 'sync_mode', 'sample clock', read_only=ro,
                                   choices=c.SYNC_MODES)
        self.timeout_s = c.declare(self, d, 'lockstep_timeout_s',
                                   'lockstep: warn when no drive within this time (s)',
                                   0.001, 3600.0)
        self.autostart = c.declare(self, d, 'autostart', 'start the clock without ~/run',
                                   read_only=ro)
        diag_period = c.declare(self, d, 'diagnostics_period_s', '/diagnostics period (s)',
                                0.01, 60.0, ro)
        self.power_every = c.declare(self, d, 'optical_power_every',
                                     'publish optical_power every N samples (1); 0: off '
                                     '(the alignment sequencer needs 1)', 0, 1000000)
        c.declare_priority(self, d)
        self.add_on_set_parameters_callback(self._on_set)
        params = {k: self.get_parameter(k).value for k in PLANT_KEYS}
        self.plant = SimulatedActuator.from_params(params)
        self.period_s = self.plant.period_s
        optics_params = {}
        for name, value in sorted(c.flatten_defaults(d, 'optics').items()):
            optics_params[name] = c.declare(self, {name: value}, name,
                                            'optics model parameter (SI, see optics.yaml)',
                                            read_only=ro)
        self.optics = OpticalLink.from_params(optics_params, seed=int(params['seed'])) \
            if optics_params else None

        self.slack = c.slack_of(bus)
        self.pub_disp = c.Pub(self, JointState, 'displacement', c.CONTROL_QOS, bus,
                              slack=self.slack)
        self.pub_power = c.Pub(self, Float64, 'optical_power', c.CONTROL_QOS, bus)
        self.pub_clock = None
        if self.sync_mode == 'lockstep':
            self.pub_clock = self.create_publisher(ClockMsg, '/clock', c.CLOCK_QOS)
        self._js = JointState(name=[JOINT_NAME], position=[0.0], velocity=[0.0])
        self._power = Float64()
        c.subscription(self, Float64, 'drive_voltage', self._on_drive,
                       c.LOCKSTEP_QOS if self.sync_mode == 'lockstep' else c.DAC_QOS, bus)
        self.create_service(SetBool, '~/run', self._on_run)
        self.health = c.Health(self, diag_period, slack=self.slack)
        if self.sync_mode == 'realtime':
            self.health.cycle = CycleStats(self.rate_hz)

        self.running = False
        self.started = False
        self.k = 0                      # index of the last published sample
        self.n_disp = 0
        self.n_power = 0
        self.n_clock = 0
        self.n_drive = 0
        self.v_latest = 0.0
        self.pending = []               # lockstep: drives not yet applied
        self._advancing = False         # lockstep: _advance is on the stack (local bus)
        # lockstep only: the EventsExecutor of a realtime process has no guard conditions
        self._next = self.create_guard_condition(self._advance) \
            if self.sync_mode == 'lockstep' else None
        self.wait_since = None
        self.holds = 0
        # realtime: sample clock and latency bookkeeping (perf_counter seconds)
        self.u_latched = 0.0            # drive held over the present period (V)
        self.period_ns = int(round(self.period_s * 1e9))
        self.wall0_ns = 0               # system time (ns) of the nominal tick 0
        self.m0 = None                  # scheduled time (s) of the first tick
        self.drives_in_period = 0
        self.writes = []                # realtime: drives received since the last tick
        self.deferred = False           # realtime: a stall's catch-up waits one tick
        self.t_pub = None
        self.drive_seen = True
        self.lat = LatencyHistogram()   # realtime: sample-to-drive latencies (s)
        self.reset_stats()
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if self.sync_mode == 'realtime':
            self.timer = self.create_timer(self.period_s, self._on_tick, clock=steady)
            self.create_timer(diag_period, lambda: self.slack.submit(self._update_values),
                              clock=steady)
        else:
            self.timer = self.create_timer(min(0.1, self.timeout_s / 2), self._on_watch,
                                           clock=steady)
        self._autostart_timer = self.create_timer(0.05, self._maybe_autostart, clock=steady)
        self.health.status(0, 'ready, waiting for run' if not self.autostart else 'ready')
        self.get_logger().info('plant ready: %s mode at %g Hz, optics %s'
                               % (self.sync_mode, self.rate_hz,
                                  'on' if self.optics else 'not installed'))

    # -- parameters -----------------------------------------------------------------
    def _on_set(self, params):
        """Check live updates (``lockstep_timeout_s`` and ``optical_power_every``)."""
        res = c.check_parameters(params, {'lockstep_timeout_s': (0.001, 3600.0),
                                          'optical_power_every': (0, 1000000)})
        if res.successful:
            for p in params:
                if p.name == 'lockstep_timeout_s':
                    self.timeout_s = float(p.value)
                elif p.name == 'optical_power_every':
                    self.power_every = int(p.value)
        return res

    # -- start / hold ---------------------------------------------------------------
    def _maybe_autostart(self):
        # realtime too waits to hear a driver: a restarted plant sampling before its drive
        # reader matched left the loop open and the controller wound up (100 V, 158 um)
        if self.autostart and not self.started and self.count_publishers(
                self.resolve_topic_name('drive_voltage')) > 0 and (
                self.sync_mode == 'realtime'
                or self.count_subscribers(self.pub_disp.topic_name) > 0):
            self._start()

    def _on_run(self, request, response):
        """Start (``data`` true) or hold (false) the sample clock."""
        if request.data:
            self._start()
        else:
            self.running, self.m0 = False, None
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

    # -- publishing -----------------------------------------------------------------
    def _publish_sample(self, t_s):
        """
        Publish /clock (lockstep), displacement and optical power for sample ``self.k``.

        :param t_s: lockstep sample time (s); realtime stamps with the nominal time of
            the tick on the system clock (the ROS clock of a realtime graph), so that the
            stamps of samples k and j differ by exactly (k - j) periods.
        """
        js = self._js
        stamp = js.header.stamp
        if self.sync_mode == 'lockstep':
            ns = int(round(t_s * 1e9))
        else:
            ns = self.wall0_ns + self.k * self.period_ns
        stamp.sec, stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
        if self.pub_clock is not None:
            self.pub_clock.publish(ClockMsg(clock=stamp))
            self.n_clock += 1
        plant = self.plant
        js.position[0] = float(plant.y_meas)
        js.velocity[0] = float(plant.velocity_m_per_s)
        self.pub_disp.publish(js)
        self.n_disp += 1
        if self.optics is not None and self.power_every and self.k % self.power_every == 0:
            msg = self._power
            msg.data = float(self.optics.measure(self.k * self.period_s, plant.position_m,
                                                 self.period_s))
            self.pub_power.publish(msg)
            self.n_power += 1

    # -- drive ----------------------------------------------------------------------
    def _on_drive(self, msg):
        """Take a drive command (V); realtime: keep the newest for the next tick."""
        self.n_drive += 1
        if self.sync_mode == 'realtime':
            self.v_latest = msg.data
            self.drives_in_period += 1
            if len(self.writes) < c.SAMPLE_DEPTH:
                self.writes.append(msg.data)
            if not self.drive_seen:
                self.drive_seen = True
                lat = time.perf_counter() - self.t_pub
                self.health.cycle.record(lat, self.k)
                if self.k >= self.stats_from:
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
            v = self.pending.pop(0)
            self.v_latest = v
            self.plant.step(v)
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
        """Realtime: one tick of the sample clock (see the module docstring)."""
        if not self.running:
            self.writes.clear()
            return
        period = self.period_s
        until = self.timer.time_until_next_call()
        now = time.perf_counter()
        # scheduled time of this tick: the timer's next call minus one period
        sched = now + (until * 1e-9 if until is not None else 0.0) - period
        fresh = self.n_disp == 0
        if self.m0 is None:
            # first tick after a start: sample 0 (plant at rest) or the next sample
            k_next = self.k + (0 if fresh else 1)
            self.m0 = sched - k_next * period
            self.wall0_ns = time.time_ns() - int(round((now - sched) * 1e9)) \
                - k_next * self.period_ns
        steps = int(round((sched - self.m0) / period)) - self.k
        if fresh:
            steps = 0
        else:
            steps = max(1, steps)
            if steps > c.MAX_CATCH_UP and not self.deferred:
                self.deferred = True    # a stall: its drives may still be on their way
                return
            self.deferred = False
            if self.drives_in_period == 0 and self.n_drive > 0 \
                    and self.k >= self.stats_from:
                self.missed += 1
            if self.k >= self.stats_from:
                self.skipped += steps - 1
            self.plant.step(self.u_latched)
            if steps > 1:               # periods this late tick skipped (docstring)
                for v in replay_edges(self.u_latched, self.writes, steps)[:-1]:
                    self.plant.step(v)
        self.k += steps
        self.writes.clear()
        # latch first: in a composed process the drive computed from this sample
        # arrives inside _publish_sample (in-process delivery) and is for the next tick
        self.u_latched = self.v_latest
        self.drives_in_period = 0
        self.drive_seen = False
        self.t_pub = time.perf_counter()
        self._publish_sample(0.0)

    def reset_stats(self, warmup=WARMUP_SAMPLES):
        """Restart the realtime statistics ``warmup`` samples from now (0: at once)."""
        self.stats_from = self.k + int(warmup)
        self.lat = LatencyHistogram()
        self.missed = 0
        self.skipped = 0

    def latency_stats(self):
        """Return the realtime loop statistics since :meth:`reset_stats` (loop_summary)."""
        return loop_summary(self.lat, max(0, self.k - self.stats_from),
                            self.missed, self.skipped, self.k + 1 if self.started else 0)

    def _update_values(self):
        vals = {'sample': self.k, 'sim_time_s': self.k * self.period_s,
                'position_m': self.plant.position_m, 'drive_v': self.plant.v_applied,
                'lockstep_holds': self.holds}
        if self.sync_mode == 'realtime':
            vals.update(self.latency_stats())
        vals.update({'sent.displacement': self.n_disp, 'sent.optical_power': self.n_power,
                     'sent.clock': self.n_clock})
        self.health.set_values(**vals)

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'displacement': self.n_disp, 'optical_power': self.n_power,
                '/clock': self.n_clock}


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    stop = c.init(args)
    node = None
    try:
        node = SimulatedActuatorNode()
        c.spin(node, realtime=node.sync_mode == 'realtime',
               priority=c.node_priority(node), stop=stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except c.NODE_ERRORS as exc:
        return c.refuse(NODE_NAME, exc)
    finally:
        c.finish(node)
    return 0


if __name__ == '__main__':
    sys.exit(main())
