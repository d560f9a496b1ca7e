# SPDX-License-Identifier: Apache-2.0
"""
``actuator_driver``: a managed (lifecycle) node around :class:`DriverCore`.

Sums ``feedforward_voltage`` and ``feedback_voltage`` (std_msgs/Float64, V), clamps and
slew-limits them and publishes ``drive_voltage`` (V) while active (lockstep: the i-th of
each; realtime: the newest, on each feedback, and on each feedforward while the feedback
is late). ``~/enable`` false ramps to the safe voltage. The realtime
watchdog ramps to ``safe_voltage_v`` when the input stops for ``watchdog_timeout_s``,
resumes after ``RECOVERY_S`` of fresh input, and latches after ``latch_trips`` trips
within ``latch_window_s`` (until ``~/enable`` true or a lifecycle cycle); ``drive_held``
(latched Bool) parks the compensator and the controller for a bumpless resume. The
voltage limits are checked against both field limits of the PZT layers. ``backend``
``mdt693b`` drives a Thorlabs MDT693B channel (:mod:`fiber_align.nodes._driver_device`);
``sensorless`` drives the feedforward alone. The realtime input rules are
:class:`fiber_align.control.realtime.DriverStep`'s. The full behaviour, with the reasons:
docs/ros_interface.md, section "actuator_driver".
"""

import sys

from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool

from fiber_align.config import ConfigError
from fiber_align.control.cycle import CycleStats
from fiber_align.control.driver import check_field_limits, DriverCore
from fiber_align.control.realtime import DriverStep
from fiber_align.graph.registry import NODES
from fiber_align.nodes._driver_device import DeviceBackend
from fiber_align.nodes._driver_loop import DriverLoop
from fiber_align.nodes._driver_params import declare_all, DriverParameters
from fiber_align.nodes.ros.bus import Pub, release_timer, sample_timer, sender_of, slack_of
from fiber_align.nodes.ros.bus import subscription, unsubscribe
from fiber_align.nodes.ros.diagnostics import ERROR, Health, OK, WARN
from fiber_align.nodes.ros.lifecycle import guard_change_state
from fiber_align.nodes.ros.params import node_defaults
from fiber_align.nodes.ros.qos import LATCHED_QOS, sample_pub_qos, sample_qos
from fiber_align.nodes.ros.runtime import run_node

#: the registry's entry of this node: its name and params files
SPEC = NODES['actuator_driver']


class ActuatorDriverNode(DriverParameters, DeviceBackend, DriverLoop, LifecycleNode):
    """Lifecycle transport around :class:`DriverCore`."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare parameters (defaults from config/); nothing is created until configure.

        :param bus: the :class:`~fiber_align.nodes.ros.bus.LocalBus` of a composed
            process, or ``None``.
        """
        super().__init__(SPEC.node, **kwargs)
        self.bus = bus
        self.slack = slack_of(bus)
        d = node_defaults(SPEC.node, SPEC.configs)
        declare_all(self, d)
        self.backend = self.get_parameter('backend').value
        self.sensorless = bool(self.get_parameter('sensorless').value)
        why = check_field_limits(self._core_params())
        if why:
            raise ConfigError('actuator_driver: %s' % why)
        self.add_on_set_parameters_callback(self._on_set)
        self.core = None
        self.pub = None
        self.out = None                 # DeviceOutput of the mdt693b backend
        self.pub_rb = None
        self.lost = None                # one-line reason once the device is lost
        self._rb_t = None
        self.enabled = True
        self.active = False
        self.n_drive = 0
        self.ff_q = []
        self.fb_q = []
        self._msg = Float64()
        self.rt = None                  # realtime: the input rules (DriverStep)
        self.i = 0
        self._subs = []
        self._timer = None
        self._srv = None
        self.held = None                # last value published on drive_held
        self.pub_held = Pub(self, Bool, 'drive_held', LATCHED_QOS, bus, latched=True)
        self._set_held(True, 'unconfigured')
        self.health = Health(self, self.get_parameter('diagnostics_period_s').value,
                             slack=self.slack, sender=sender_of(bus))
        self.health.status(WARN, 'unconfigured: output 0 V')
        self._report_protections(self._core_params())
        self.refused_transitions = 0
        guard_change_state(self)

    # -- lifecycle ------------------------------------------------------------------
    def _refuse(self, why):
        self.get_logger().error('cannot configure: %s' % why)
        self.health.status(ERROR, why)
        self.health.error(why)                          # on /diagnostics at once
        self.core = None
        return TransitionCallbackReturn.FAILURE

    def on_configure(self, state):
        """Build the core, open the device (mdt693b) and the transport; nothing published."""
        p = self._core_params()
        why = self._check_core(p)
        if why:
            return self._refuse(why)
        self.period_s = 1.0 / float(self.get_parameter('rate_hz').value)
        self.core = DriverCore.from_params(p, ramp_period_s=self.period_s)
        self.rt = DriverStep(self.core, self.period_s, self.get_logger().info)
        self.lockstep = self.get_parameter('sync_mode').value == 'lockstep'
        why = self._open_device(Float64)
        if why:
            return self._refuse(why)
        self.pub = Pub(self, Float64, 'drive_voltage', sample_pub_qos(self.lockstep), self.bus,
                       slack=self.slack)
        qos = sample_qos(self.lockstep)
        self._subs = [
            subscription(self, Float64, 'feedforward_voltage', self._on_ff, qos, self.bus)]
        if not self.sensorless:
            self._subs.append(subscription(self, Float64, 'feedback_voltage', self._on_fb,
                                           qos, self.bus))
        self._srv = self.create_service(SetBool, '~/enable', self._on_enable)
        if not self.lockstep:
            self._timer = sample_timer(self, self.bus, self.watchdog_period_s(), self._on_tick,
                                       Clock(clock_type=ClockType.STEADY_TIME), watchdog=True)
            self.health.cycle = CycleStats(1.0 / self.period_s)     # feedforward to drive
        self.health.resolve()                           # a refusal before this is over
        self.health.status(OK, 'configured (inactive): output %g V' % self.core.v)
        self._update_values()
        return TransitionCallbackReturn.SUCCESS

    def watchdog_period_s(self):
        """Return the watchdog period (s): one control period (each ramp step is one)."""
        return self.period_s

    def on_activate(self, state):
        """Start publishing drive commands (a lifecycle cycle re-arms a latched watchdog)."""
        if self.core.latched:
            self.core.rearm()
            self.get_logger().info('watchdog latch re-armed by activate')
        self.core.restart_watchdog()    # the inactive time is no loss of input
        self.active = True
        self._set_held(not self.enabled or self.core.tripped, 'activated')
        if self.lockstep:
            self._pair()        # the pairs that came between configure and activate
        self.health.status(OK, 'active')
        self.get_logger().info('active: %s pairing, %g..%g V'
                               % ('lockstep' if self.lockstep else 'latest',
                                  self.core.v_min, self.core.v_max))
        return super().on_activate(state)

    def on_deactivate(self, state):
        """Stop following ff + fb; ramp to the safe voltage (realtime) and hold it there."""
        if self.pub is not None and self.core is not None and self.lockstep:
            self._publish(self.core.safe)
        elif self.core is not None:
            self.core.start_safe_ramp(self._now())
        self.active = False
        self._set_held(True, 'deactivated')
        if self._ramp_device():
            return TransitionCallbackReturn.ERROR       # on_error closes the device
        safe = self.core.safe if self.core else 0.0
        if self.out is not None:
            self._publish(safe)                         # the device is at it already
            self.out.start()                            # read-back only (nothing pending)
        self.health.status(OK, 'inactive: output %g V' % safe)
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        """Destroy the transport and the core; close the device (the output stays)."""
        if self.lost is not None:
            return TransitionCallbackReturn.ERROR
        self._teardown()
        self.health.status(WARN, 'unconfigured: output 0 V')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        """Ramp the device to the safe voltage, then tear down."""
        self._ramp_device()
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state):
        """Close a lost device and end unconfigured (a later configure reconnects)."""
        why = self.lost or 'a transition failed'
        self._teardown()
        self.health.status(ERROR, 'device lost: %s; unconfigured: a configure reconnects'
                           % why)
        return TransitionCallbackReturn.SUCCESS

    def _teardown(self):
        self._close_device()
        for s in self._subs:
            unsubscribe(self, s)
        self._subs = []
        if self._timer is not None:
            release_timer(self, self._timer, self._on_tick)
            self._timer = None
        if self._srv is not None:
            self.destroy_service(self._srv)
            self._srv = None
        if self.pub is not None:
            self.pub.destroy(self)
            self.pub = None
        self.core = None
        self.active = False
        self.ff_q, self.fb_q = [], []
        self._set_held(True, 'unconfigured')


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(ActuatorDriverNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
