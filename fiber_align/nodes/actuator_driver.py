# SPDX-License-Identifier: Apache-2.0
"""
``actuator_driver``: the one driver, a managed (lifecycle) node for the axes of one device.

Per axis ``a`` of ``axes`` (``['']``: the 1-D names; ``[x, y]``: ``x/...``): in
``a/feedforward_voltage``, ``a/feedback_voltage``; out ``a/drive_voltage``, ``a/drive_held``,
``a/drive_voltage_readback`` (V). Rules: :class:`~fiber_align.control.driver_axes.DriverAxes`;
transitions: :class:`~fiber_align.hardware.driver_session.DriverSession` (docs/ros_interface.md).
"""

import sys
import time

from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn as Ret
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool

from fiber_align.config import ConfigError, load_params
from fiber_align.control.cycle import CycleStats
from fiber_align.control.driver_axes import (AXIS_KEYS, axis_name, axis_topic as topic, INPUTS,
                                             LIMIT_KEYS, limit_updates, SETTINGS, SHARED_KEYS)
from fiber_align.graph.checks import protections_off_texts
from fiber_align.graph.registry import NODES
from fiber_align.hardware.driver_session import IDLE_OUTPUT, open_session, refusal
from fiber_align.hardware.mdt693b_session import backend_defaults, DEVICE_KEYS, parameter_rows
from fiber_align.nodes.ros import bus as b
from fiber_align.nodes.ros.diagnostics import ERROR, Health, LEVELS
from fiber_align.nodes.ros.lifecycle import guard_change_state
from fiber_align.nodes.ros.owners import watch_drives
from fiber_align.nodes.ros.params import (check_parameters, declare, declare_graph_values,
                                          declare_rows, flatten_defaults, node_defaults,
                                          PRIORITY)
from fiber_align.nodes.ros.qos import LATCHED_QOS, sample_pub_qos, sample_qos
from fiber_align.nodes.ros.runtime import run_node

#: the registry's entry of this node: its name and params files
SPEC = NODES['actuator_driver']


class ActuatorDriverNode(LifecycleNode):
    """Lifecycle transport around a :class:`~fiber_align.hardware.driver_session.DriverSession`."""

    def __init__(self, bus=None, node_name=SPEC.node, **kwargs):
        """Declare the parameters (defaults from config/); nothing is built until configure."""
        super().__init__(node_name, **kwargs)
        self.bus, self.slack = bus, b.slack_of(bus)
        d = dict(node_defaults(SPEC.node, SPEC.configs))
        g = declare_graph_values(self, d, 'rate_hz', 'sync_mode', 'sensorless',
                                 'diagnostics_period_s', *PRIORITY)
        self.period_s, self.lockstep = 1.0 / float(g['rate_hz']), g['sync_mode'] == 'lockstep'
        self.sensorless, self.enabled = bool(g['sensorless']), True
        for k, (text, lo, hi, choices) in SETTINGS.items():
            setattr(self, k, declare(self, d, k, text, lo, hi, True, choices=choices))
            d.update(backend_defaults(self.backend, load_params('hardware.yaml', SPEC.node),
                                      load_params('hardware.yaml', '/**')['port'])
                     if k == 'backend' else {})
        self.axes = [str(a) for a in self.axes]
        [d.update(flatten_defaults(d, a)) for a in self.axes if a]     # <axis>.<key>
        self.ranges = declare_rows(self, parameter_rows(self.axes, d))
        why = refusal({a: self._params(a) for a in self.axes},
                      {} if self.backend == 'mdt693b' else None)
        if why:
            raise ConfigError('%s: %s' % (self.get_name(), why))
        self.add_on_set_parameters_callback(self._on_set)
        self.s = self._timer = self._srv = self.held = self.watch = None
        self.pubs, self.subs, self.sent, self._ticks, self._off = {}, [], {}, 0, set()
        self.pub_held = [b.Pub(self, Bool, topic(a, 'drive_held'), LATCHED_QOS, bus,
                               latched=True) for a in self.axes]
        diag_s, fqn = g['diagnostics_period_s'], self.get_fully_qualified_name()
        self.health = Health(self, diag_s, slack=self.slack, sender=b.sender_of(bus))
        self.status = {a: Health(self, diag_s, name='%s/%s' % (fqn, a)) if a else self.health
                       for a in self.axes}
        self._idle = 'unconfigured: output ' + IDLE_OUTPUT[self.backend]
        self._report([('warn', None, self._idle)], 'unconfigured')
        self._protections()
        guard_change_state(self)

    def _params(self, axis, new=None):
        p = {k: self.get_parameter(k).value for k in SHARED_KEYS + LIMIT_KEYS}
        p.update({k: self.get_parameter(axis_name(axis, k)).value for k in AXIS_KEYS})
        return dict(p, **(new or {}))

    def on_configure(self, state):
        """Build the session, open the device (ramped to safe) and the topics."""
        device = {k: self.get_parameter(k).value for k in DEVICE_KEYS} if \
            self.backend == 'mdt693b' else None
        self.s, why = open_session({a: self._params(a) for a in self.axes}, self.period_s,
                                   device, self.lockstep, self.sensorless, self.enabled,
                                   self.get_logger().info)
        if why:
            self._report([('refused', '', why)])        # on /diagnostics at once
            self._teardown()
            return Ret.FAILURE
        pq, sq = sample_pub_qos(self.lockstep), sample_qos(self.lockstep)
        outs = ('drive_voltage', 'drive_voltage_readback')[:1 + self.s.device]
        self.pubs = {(a, n): b.Pub(self, Float64, topic(a, n), pq, self.bus, slack=self.slack)
                     for a in self.axes for n in outs}
        self.msgs = {a: Float64() for a in self.axes}
        self.watch = watch_drives(self, self.axes, self._on_foreign)    # off this thread
        self.subs = [b.subscription(self, Float64, topic(a, n), lambda m, a=a, ff=ff:
                                    self._on_input(a, ff, m.data), sq, self.bus, self.watch)
                     for a in self.axes for n, ff in INPUTS if ff or not self.sensorless]
        self._srv = self.create_service(SetBool, '~/enable', self._on_enable)
        if not self.lockstep:
            self._timer = b.sample_timer(self, self.bus, self.period_s, self._on_tick,
                                         Clock(clock_type=ClockType.STEADY_TIME), True)
            self.health.cycle = CycleStats(1.0 / self.period_s)     # feedforward to drive
        self.health.resolve()                           # a refusal before this is over
        self._report([])
        self._values()
        return Ret.SUCCESS

    def on_activate(self, state):
        """Follow the inputs (a lifecycle cycle re-arms a latched watchdog)."""
        self._drive(self.s.activate())
        self._report([], 'activated')
        return super().on_activate(state)

    def on_deactivate(self, state):
        """Follow no more; ramp every axis to its safe voltage and hold it there."""
        self._drive(self.s.deactivate(time.monotonic()))
        self._report([], 'deactivated')
        return Ret.ERROR if self.s.lost else super().on_deactivate(state)

    def on_cleanup(self, state):
        """Close the device (its outputs stay); destroy the topics and the session."""
        return Ret.ERROR if self.s.lost else self._teardown(('warn', None, self._idle))

    def on_shutdown(self, state):
        """Ramp the device to the safe voltages, then tear down."""
        return self.close() or self._teardown()

    def on_error(self, state):
        """Close a lost device and end unconfigured (a later configure reconnects)."""
        return self._teardown(('fail', None, 'device lost: %s; unconfigured: a configure '
                               'reconnects' % (self.s and self.s.lost or 'a transition failed')))

    def _teardown(self, *reports):
        self.watch = self.watch and self.watch.close()
        self._report([])                                # the session's last words
        self.s = self.s and self.s.close()
        [b.unsubscribe(self, sub) for sub in self.subs]
        [p.destroy(self) for p in self.pubs.values()]
        self._timer and b.release_timer(self, self._timer, self._on_tick)
        self._srv and self.destroy_service(self._srv)
        self.pubs, self.subs, self._timer, self._srv = {}, [], None, None
        self._report(list(reports), 'unconfigured')
        return Ret.SUCCESS

    def close(self):
        """Process exit: stop the watch (its thread holds the rcl node), ramp, close."""
        self.watch = getattr(self, 'watch', None) and self.watch.close()
        if getattr(self, 's', None) is not None:
            self.s.ramp()
            self.s.close()

    def destroy_node(self):
        """Ramp and close the device (:meth:`close`), then destroy the node."""
        return self.close() or super().destroy_node()

    def _on_input(self, axis, ff, v):
        if self.s is not None:
            self._drive(self.s.input(axis, ff, v, time.monotonic()))
            self.s.reports and self._report([], 'input is back')
            t_ff, cycle = self.s.driver.steps[axis].t_ff, self.health.cycle
            if cycle is not None and t_ff is not None and not self.lockstep:
                cycle.record(time.monotonic() - t_ff)

    def _drive(self, drives, name='drive_voltage'):
        for a, v in drives:
            msg = self.msgs[a] if name == 'drive_voltage' else Float64()
            msg.data = float(v)
            self.pubs[a, name].publish(msg)
            self.sent[a, name] = self.sent.get((a, name), 0) + 1

    def _on_tick(self):             # every period: the device, every axis's watchdog
        if self.s is None:
            return
        drives, readbacks, lost = self.s.tick(time.monotonic())
        self._drive(drives)
        self._drive(readbacks.items(), 'drive_voltage_readback')
        self.s.reports and self._report([], 'device lost' if lost else 'watchdog')
        if lost:      # the transition returns ERROR (s.lost): on_error closes the port
            return self.trigger_deactivate() if self.s.driver.active else self.trigger_cleanup()
        self._ticks += 1
        self._ticks % 20 or self._values()

    def _report(self, reports, held_reason=None):   # the session's reports, then these
        for kind, a, text in (self.s.take_reports() if self.s else []) + reports:
            targets = set(self.status.values()) | {self.health} if a is None else \
                {self.status.get(a, self.health)}
            if kind in ('error', 'refused'):
                self.get_logger().error('cannot configure: ' * (kind == 'refused') + text)
                [h.error(text) for h in targets]
            elif kind == 'info':
                self.get_logger().info(text)
            [h.summary(LEVELS.get(kind, ERROR), text) for h in targets if kind != 'info']
        held = self.s is None or self.s.held
        if held != self.held:
            self.held = held
            [pub.publish(Bool(data=held)) for pub in self.pub_held]
            self.get_logger().info('drive_held %s (%s)' % (str(held).lower(), held_reason))

    def _on_enable(self, request, response):    # false: every axis ramps to its safe voltage
        self.enabled = bool(request.data)
        self.s and self.s.enable(self.enabled, time.monotonic())
        response.success, response.message = True, 'output %s' % (
            'enabled' if self.enabled else 'disabled: ramping to the safe voltage')
        self._report([('info', None, response.message)], 'enable %s' % self.enabled)
        return response

    def _on_set(self, params):      # limits in range and consistent on every axis
        res = check_parameters(params, self.ranges)
        new, why = limit_updates(self.axes, {p.name: p.value for p in params}, self._params) \
            if res.successful else ({}, None)
        if why:
            res.successful, res.reason = False, why
        elif new:
            [self.s.driver.set_limits(a, n) for a, n in new.items() if self.s]
            self._protections(new)
        return res

    def _protections(self, new=None):   # each one the limits turn off: a WARN, log and diag
        off = protections_off_texts(self._params(a, (new or {}).get(a)) for a in self.axes)
        [self.get_logger().warning('protection off: %s' % t) for t in set(off) - self._off]
        self._off = set(off)
        self.health.condition('protections', 'protection off: %s' % '; '.join(off) if off
                              else None)

    def _on_foreign(self, lines):   # a second publisher of a command or drive topic: hold
        self.s.intrusion('; '.join(lines) or None, self.watch.pending)
        self._report([], 'foreign publisher')

    def _values(self):
        self.health.set_values(**self.s.values())
        [self.status[a].set_values(**self.s.values(a)) for a in self.axes]

    def sent_counts(self):
        """Return published message counts per topic."""
        return {topic(a, n): c for (a, n), c in self.sent.items()}


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(ActuatorDriverNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
