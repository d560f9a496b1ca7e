# SPDX-License-Identifier: Apache-2.0
"""
``simulated_actuator``: the plant and sensor of the control core as a ROS 2 node.

Wraps :class:`fiber_align.plant.actuator.SimulatedActuator` (one ``step(v)`` = one control
period); the same executable is each axis's plant of the rig and the station. Topics
(relative names, SI units):

- sub ``drive_voltage`` (std_msgs/Float64, V): the amplifier input, held for one period.
- pub ``displacement`` (sensor_msgs/JointState, joint ``bimorph_tip``): position = the
  sensor reading (m), velocity = the tip velocity (m/s); stamp = the sample time t_k.
- pub ``optical_power`` (std_msgs/Float64, W): the 1-D optics model's detector reading,
  every ``optical_power_every`` samples (0: off; the multi-axis graphs: their optics node).
- pub ``tip_position`` (sensor_msgs/JointState: the true tip position, m, and velocity,
  m/s, the stamp of ``displacement``) every ``tip_position_every`` samples (0: off, no
  publisher; the rig and the station set 1 for their optics node).
- pub ``/clock`` (rosgraph_msgs/Clock) in lockstep when ``publish_clock`` (a multi-axis
  graph leaves it to its first axis's plant).
- srv ``~/run`` (std_srvs/SetBool): start (true) or hold (false) the sample clock.

``lockstep`` publishes sample k with ``/clock`` = k T and advances to k + 1 once the drive
for sample k arrived (a WARN after ``lockstep_timeout_s`` without): exactly the offline
loop of docs/CONTRACTS.md. ``realtime`` runs a sample clock on the steady wall clock at
``rate_hz`` (:class:`fiber_align.plant.dac.DacClock`): at tick k it advances the plant
with the drive latched at tick k-1, publishes y_k (stamp t_0 + k T) and latches the
newest drive, one period more delay than lockstep. The sample clock:
:class:`fiber_align.nodes.ros.plant_clock.PlantClock` (composed); the realtime latency and
missed cycles: its ``latency_stats()`` and ``cycle.*`` on ``/diagnostics``.
"""

import sys
import time

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool

from fiber_align.control.cycle import cycle_warning, CycleStats, RecentShare
from fiber_align.graph.ranges import PLANT_RANGES
from fiber_align.graph.registry import NODES
from fiber_align.nodes.ros.plant_clock import PlantClock
from fiber_align.nodes.ros.bus import Pub, sender_of, slack_of, subscription
from fiber_align.nodes.ros.diagnostics import Health
from fiber_align.nodes.ros.params import check_parameters, declare, declare_graph_values
from fiber_align.nodes.ros.params import declare_row
from fiber_align.nodes.ros.params import flatten_defaults, node_defaults, PRIORITY
from fiber_align.nodes.ros.qos import CLOCK_QOS, DAC_QOS, LATCHED_QOS, LOCKSTEP_QOS
from fiber_align.nodes.ros.qos import sample_pub_qos
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.plant.actuator import KINDS, SimulatedActuator
from fiber_align.plant.optics import OpticalLink

#: the registry's entry of this node: its name and params files
SPEC = NODES['simulated_actuator']
JOINT_NAME = 'bimorph_tip'
#: The values a running plant takes (its other parameters are read-only).
LIVE = ('lockstep_timeout_s', 'optical_power_every', 'cycle_goal_missed_share')
PLANT_KEYS = ('rate_hz', 'hysteresis', 'omega_n_rad_s', 'damping_ratio', 'v_min', 'v_max',
              'slew_rate_v_per_s', 'noise_rms_m', 'resolution_m', 'seed')


class SimulatedActuatorNode(Node):
    """Transport, parameters and health around :class:`SimulatedActuator`."""

    def __init__(self, bus=None, **kwargs):
        """Declare the parameters, build the plant, wire topics (``bus``: a LocalBus)."""
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        ro = True
        g = declare_graph_values(self, d, 'rate_hz', 'sync_mode', 'diagnostics_period_s',
                                 *PRIORITY)
        self.rate_hz, self.sync_mode = g['rate_hz'], g['sync_mode']
        declare(self, d, 'hysteresis', 'true hysteresis law of the plant', read_only=ro,
                choices=KINDS)
        for name in ('omega_n_rad_s', 'damping_ratio', 'v_min', 'v_max', 'slew_rate_v_per_s',
                     'noise_rms_m', 'resolution_m', 'seed'):
            declare_row(self, d, PLANT_RANGES, name, ro)
        self.cycle_goal = declare_row(self, d, PLANT_RANGES, 'cycle_goal_missed_share', False)
        self.timeout_s = declare_row(self, d, PLANT_RANGES, 'lockstep_timeout_s', False)
        start = {'autostart': declare(self, d, 'autostart', 'start the clock without ~/run',
                                      read_only=ro),
                 'start_after_reader': declare(
                     self, d, 'start_after_reader', 'realtime: start the clock once this '
                     'node subscribes to displacement and drive_voltage (a name in this '
                     'namespace or a full one, /ns/name; "" = none)', read_only=ro),
                 'start_wait_s': declare_row(self, d, PLANT_RANGES, 'start_wait_s', ro)}
        diag_period = g['diagnostics_period_s']
        self.power_every = declare_row(self, d, PLANT_RANGES, 'optical_power_every', False)
        self.add_on_set_parameters_callback(self._on_set)
        params = {k: self.get_parameter(k).value for k in PLANT_KEYS}
        self.plant = SimulatedActuator.from_params(params)
        self.period_s = self.plant.period_s
        optics_params = {}
        for name, value in sorted(flatten_defaults(d, 'optics').items()):
            optics_params[name] = declare(self, {name: value}, name,
                                          'optics model parameter (SI, see optics.yaml)',
                                          read_only=ro)
        self.optics = OpticalLink.from_params(optics_params, seed=int(params['seed']),
                                              sample_period_s=self.period_s) \
            if optics_params else None
        self.slack = slack_of(bus)
        pub_qos = sample_pub_qos(self.sync_mode == 'lockstep')
        self.pub_disp = Pub(self, JointState, 'displacement', pub_qos, bus,
                            slack=self.slack)
        self.pub_power = Pub(self, Float64, 'optical_power', pub_qos, bus)
        clock = declare(self, d, 'publish_clock', 'lockstep: publish /clock (a multi-axis '
                        'graph: its first plant only)', read_only=ro)
        self.pub_clock = self.create_publisher(ClockMsg, '/clock', CLOCK_QOS) \
            if clock and self.sync_mode == 'lockstep' else None
        self.tip_every = declare_row(self, d, PLANT_RANGES, 'tip_position_every', ro)
        self.pub_tip = Pub(self, JointState, 'tip_position', pub_qos, bus) \
            if self.tip_every else None
        self._js = JointState(name=[JOINT_NAME], position=[0.0], velocity=[0.0])
        self._tip = JointState(name=[JOINT_NAME], position=[0.0], velocity=[0.0])
        self._power = Float64()
        self.health = Health(self, diag_period, slack=self.slack, sender=sender_of(bus))
        if self.sync_mode == 'realtime':
            self.health.cycle = CycleStats(self.rate_hz)
        self.n_disp = self.n_power = self.n_clock = self.n_tip = 0
        # the sample clock (its state, the drive, start and hold, its timers)
        self.clock = PlantClock(self, self.plant, self._publish_sample, self.health, bus, dict(
            start, sync_mode=self.sync_mode, lockstep_timeout_s=self.timeout_s,
            topics=(self.pub_disp.topic_name, self.resolve_topic_name('drive_voltage'))),
            self._update_values)
        if self.sync_mode == 'realtime':
            self.create_timer(diag_period, lambda: self.slack.submit(self._update_values),
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
            # the driver's hold: periods the loop is not meant to run are not missed
            subscription(self, Bool, 'drive_held', self.clock.on_held, LATCHED_QOS, bus)
            self.recent = RecentShare()     # the cycle WARN: the recent window's share
        subscription(self, Float64, 'drive_voltage', self.clock.on_drive,
                     LOCKSTEP_QOS if self.sync_mode == 'lockstep' else DAC_QOS, bus)
        self.create_service(SetBool, '~/run', self.clock.on_run)
        self.health.summary(0, 'ready' if start['autostart'] else 'ready, waiting for run')
        self.get_logger().info('plant ready: %s mode at %g Hz, optics %s'
                               % (self.sync_mode, self.rate_hz,
                                  'on' if self.optics else 'not installed'))

    # -- parameters -----------------------------------------------------------------
    def _on_set(self, params):
        """Check live updates (``lockstep_timeout_s``, ``optical_power_every``, the goal)."""
        res = check_parameters(params, {k: PLANT_RANGES[k][1:] for k in LIVE})
        if res.successful:
            for p in params:
                if p.name == 'lockstep_timeout_s':
                    self.timeout_s = self.clock.timeout_s = float(p.value)
                elif p.name == 'optical_power_every':
                    self.power_every = int(p.value)
                elif p.name == 'cycle_goal_missed_share':
                    self.cycle_goal = float(p.value)
        return res

    # -- publishing -----------------------------------------------------------------
    def _publish_sample(self, t_s):
        """
        Publish /clock (lockstep), displacement, power and tip for the clock's sample k.

        :param t_s: lockstep sample time (s); realtime stamps with the nominal time of
            the tick on the system clock (the ROS clock of a realtime graph), so that the
            stamps of samples k and j differ by exactly (k - j) periods.
        """
        js, k = self._js, self.clock.k
        stamp = js.header.stamp
        if self.sync_mode == 'lockstep':
            ns = int(round(t_s * 1e9))
        else:
            ns = self.clock.dac.wall0_ns + k * self.clock.dac.period_ns
        stamp.sec, stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
        if self.pub_clock is not None:
            self.pub_clock.publish(ClockMsg(clock=stamp))
            self.n_clock += 1
        plant = self.plant
        js.position[0] = float(plant.y_meas)
        js.velocity[0] = float(plant.velocity_m_per_s)
        self.pub_disp.publish(js)
        self.n_disp += 1
        if self.optics is not None and self.power_every and k % self.power_every == 0:
            msg = self._power
            msg.data = float(self.optics.measure(k * self.period_s, plant.position_m,
                                                 self.period_s))
            self.pub_power.publish(msg)
            self.n_power += 1
        if self.tip_every and k % self.tip_every == 0:
            tip = self._tip
            tip.header.stamp = stamp
            tip.position[0] = float(plant.position_m)
            tip.velocity[0] = float(plant.velocity_m_per_s)
            self.pub_tip.publish(tip)
            self.n_tip += 1

    def _update_values(self):
        c = self.clock
        vals = {'sample': c.k, 'sim_time_s': c.k * self.period_s,
                'position_m': self.plant.position_m, 'drive_v': self.plant.v_applied,
                'lockstep_holds': c.holds}
        if self.sync_mode == 'realtime':
            stats = c.latency_stats()
            recent = self.recent.update(time.monotonic(), stats['periods'],
                                        stats['missed_cycles'])
            vals.update(stats, recent_missed_share=recent['missed_share'])
            self.health.condition('cycles', cycle_warning(recent, self.cycle_goal),
                                  publish=False)
        vals.update({'sent.displacement': self.n_disp, 'sent.optical_power': self.n_power,
                     'sent.clock': self.n_clock})
        self.health.set_values(**vals)

    def sent_counts(self):
        """Return published message counts per topic."""
        out = {'displacement': self.n_disp, 'optical_power': self.n_power,
               '/clock': self.n_clock}
        return dict(out, tip_position=self.n_tip) if self.tip_every else out


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(SimulatedActuatorNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
