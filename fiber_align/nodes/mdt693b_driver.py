# SPDX-License-Identifier: Apache-2.0
"""
``mdt693b_driver``: one managed (lifecycle) node owning one MDT693B, driving several axes.

The two-axis rig on hardware has one three-channel amplifier on one serial link; two
``actuator_driver`` nodes cannot both open its port, so this node is the link's one
owner (docs/hardware.md, "The two-axis rig on hardware"). Per axis ``a`` of ``axes``
(relative names in the rig namespace, SI units):

- sub ``a/feedforward_voltage`` (std_msgs/Float64, V; sensorless: no feedback);
- pub ``a/drive_voltage`` (V, each command sent), ``a/drive_held`` (std_msgs/Bool,
  latched) and ``a/drive_voltage_readback`` (V, the channel's output read back);
- its own :class:`~fiber_align.control.driver.DriverCore` (clamp to ``a.v_min`` ..
  ``a.v_max``, slew, watchdog, latch) and
  :class:`~fiber_align.control.realtime.DriverStep` (the realtime input rules), the laws
  of ``actuator_driver``;
- ``/diagnostics`` status ``<node>/a``: channel, drive, read-back, counts, watchdog.

The device (:class:`fiber_align.nodes._driver_device.DeviceOutput`, the writer thread
``actuator_driver`` uses too) has the node's own status: port, ``id?`` line, limit switch,
achieved write rate, the last refusal and the loss. A watchdog trip of any axis holds
every axis (each ramps to its ``safe_voltage_v`` until all inputs are fresh again);
configure (from the outputs read back), deactivate, shutdown and the process's exit ramp
every axis to its safe voltage; a lost device ends in ERROR -> unconfigured (the unit
keeps its outputs until it is reached again), and a configure reconnects and ramps.

Parameters (read-only; defaults ``config/hardware_rig.yaml``, section ``mdt693b_driver``,
the field limits and latch from ``driver.yaml``, ``port`` from ``hardware.yaml``'s
``/**``): ``axes``, ``<axis>.channel``, ``<axis>.v_min``, ``<axis>.v_max``,
``<axis>.safe_voltage_v``, the device keys of ``actuator_driver`` (``port``, ``baud``,
``device_limit_v``, ``device_timeout_s``, ``ramp_rate_v_per_s``, ``ramp_step_s``,
``readback_period_s``), ``combined_write``, and the shared core keys
(``slew_rate_v_per_s``, ``watchdog_timeout_s``, ``latch_trips``, ``latch_window_s``,
``safe_ramp_rate_v_per_s``).
"""

import sys
import time

from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_msgs.msg import Bool, Float64

from fiber_align.config import ConfigError, load_params
from fiber_align.control.driver import check_field_limits, DriverCore
from fiber_align.control.realtime import DriverStep
from fiber_align.hardware import errors as er
from fiber_align.hardware.mdt693b import CHANNELS
from fiber_align.nodes._driver_device import DeviceOutput
from fiber_align.nodes._driver_params import (CORE_KEYS, DEVICE_DOCS, HARDWARE_FILE, LIMIT_KEYS,
                                              RANGES, UNITS)
from fiber_align.nodes.ros.bus import Pub, subscription, unsubscribe
from fiber_align.nodes.ros.diagnostics import ERROR, Health, OK, WARN
from fiber_align.nodes.ros.lifecycle import guard_change_state
from fiber_align.nodes.ros.params import (declare, declare_graph_values, flatten_defaults,
                                          node_defaults, PRIORITY)
from fiber_align.nodes.ros.qos import CONTROL_QOS, LATCHED_QOS, REALTIME_QOS
from fiber_align.nodes.ros.runtime import run_node

NODE_NAME = 'mdt693b_driver'
CONFIG_FILE = 'hardware_rig.yaml'
AREA_FILES = (HARDWARE_FILE, CONFIG_FILE)
#: Keys of each axis (``<axis>.<key>``).
AXIS_KEYS = ('channel', 'v_min', 'v_max', 'safe_voltage_v')
#: Core keys shared by the axes (each axis has its own core with them).
SHARED_CORE = tuple(k for k in CORE_KEYS if k not in AXIS_KEYS)
DEVICE = ('port', 'baud', 'device_limit_v', 'device_timeout_s', 'ramp_rate_v_per_s',
          'ramp_step_s', 'readback_period_s')


def defaults():
    """Return the node's defaults: driver.yaml's field limits, hardware files, own section."""
    d = {k: v for k, v in load_params('driver.yaml', 'actuator_driver').items()
         if k in LIMIT_KEYS + SHARED_CORE}
    d.update(node_defaults(NODE_NAME, AREA_FILES))
    d.setdefault('port', load_params(HARDWARE_FILE, '/**')['port'])
    return d


def check_axes(axes, channels):
    """Return None or why the axis -> channel mapping cannot be (one line)."""
    if not axes or len(set(axes)) != len(axes):
        return 'axes %r: give each axis once' % (list(axes),)
    seen = {}
    for a, ch in zip(axes, channels):
        if ch not in CHANNELS:
            return 'axis %s: channel %r is not one of x, y, z' % (a, ch)
        if ch in seen:
            return 'channel %s is named twice (axes %s and %s)' % (ch, seen[ch], a)
        seen[ch] = a
    return None


class Axis:
    """The ROS side of one axis: its core, input rules, topics and status (SI)."""

    def __init__(self, node, name, p, period_s, health, bus=None):
        """Build the core and the topics of axis ``name`` with the parameters ``p``."""
        self.name = name
        self.p = p
        self.core = DriverCore.from_params(p, ramp_period_s=period_s)
        self.rt = DriverStep(self.core, period_s, node.get_logger().info)
        self.pub = Pub(node, Float64, name + '/drive_voltage', CONTROL_QOS, bus)
        self.pub_rb = Pub(node, Float64, name + '/drive_voltage_readback', CONTROL_QOS, bus)
        self.health = health
        self.n_drive = self.n_rb = 0
        self.rb_t = None
        self.last_pub = None

    def publish(self, v, out):
        """Publish drive ``v`` (V) and hand it to the device."""
        self.pub.publish(Float64(data=float(v)))
        self.last_pub = float(v)
        self.n_drive += 1
        if out is not None:
            out.submit(float(v), self.name)

    def values(self, out):
        """Set this axis's diagnostics values."""
        c = self.core
        v = dict(channel=self.p['channel'], drive_v=c.v, v_min=c.v_min, v_max=c.v_max,
                 saturation_count=c.saturation_count, slew_count=c.slew_count,
                 watchdog_count=c.watchdog_count, nan_count=c.nan_count,
                 watchdog_latched=c.latched, **{'sent.drive_voltage': self.n_drive})
        if out is not None:
            v.update(out.values(self.name))
        self.health.set_values(**v)

    def destroy(self, node):
        """Destroy the publishers (the status stays: it reports the unconfigured axis)."""
        self.pub.destroy(node)
        self.pub_rb.destroy(node)


class Mdt693bDriverNode(LifecycleNode):
    """Lifecycle node: the MDT693B's one owner, one DriverCore per axis."""

    def __init__(self, bus=None, **kwargs):
        """Declare the parameters; refuse a bad axis mapping (ConfigError, one line)."""
        super().__init__(NODE_NAME, **kwargs)
        self.bus = bus
        d = defaults()
        g = declare_graph_values(self, d, 'rate_hz', 'sync_mode', 'sensorless',
                                 'diagnostics_period_s', *PRIORITY)
        self.period_s = 1.0 / float(g['rate_hz'])
        self.lockstep = g['sync_mode'] == 'lockstep'
        self.diag_s = float(g['diagnostics_period_s'])
        self.axes = list(declare(self, d, 'axes', 'the axes driven (each <axis>.* below)',
                                 read_only=True))
        flat = {}
        for a in self.axes:
            flat.update(flatten_defaults(d, a))
        self.axis_params = {}
        for a in self.axes:
            ap = {}
            for k in AXIS_KEYS:
                text = 'amplifier channel of axis %s' % a if k == 'channel' else \
                    '%s, axis %s' % (UNITS[k], a)
                ap[k] = declare(self, flat, '%s.%s' % (a, k), text, read_only=True)
            self.axis_params[a] = ap
        for k in SHARED_CORE:
            declare(self, d, k, UNITS[k] + ' (each axis)', *RANGES[k], read_only=True)
        for k in LIMIT_KEYS:
            declare(self, d, k, 'field limit of the PZT layers (V or 1)', read_only=True)
        for k in DEVICE:
            text, lo, hi = DEVICE_DOCS[k]
            declare(self, d, k, text, lo, hi, True)
        declare(self, d, 'combined_write', 'send the axes of one period in one xyzvoltage= '
                '(the channels no axis owns are re-sent their read-back)', read_only=True)
        why = check_axes(self.axes, [self.axis_params[a]['channel'] for a in self.axes])
        for a in self.axes:
            why = why or check_field_limits(self._core_params(a))
        if why:
            raise ConfigError('%s: %s' % (NODE_NAME, why))
        self.health = Health(self, self.diag_s)
        self.health.status(WARN, 'unconfigured: outputs untouched')
        fqn = self.get_fully_qualified_name()
        self.axis_health = {a: Health(self, self.diag_s, name='%s/%s' % (fqn, a))
                            for a in self.axes}
        for a, h in self.axis_health.items():
            h.status(WARN, 'unconfigured')
            h.set_values(channel=self.axis_params[a]['channel'])
        self.refused_transitions = 0
        self.out = None
        self.lost = None
        self.ax = {}
        self.active = False
        self._subs = []
        self._timer = None
        self._ticks = 0
        self.held = {a: None for a in self.axes}
        self.pub_held = {a: Pub(self, Bool, a + '/drive_held', LATCHED_QOS, bus,
                                latched=True) for a in self.axes}
        self._set_held(True, 'unconfigured')
        guard_change_state(self)

    # -- parameters -----------------------------------------------------------------
    def _core_params(self, axis):
        p = {k: self.get_parameter(k).value for k in SHARED_CORE + LIMIT_KEYS}
        p.update(self.axis_params[axis])
        return p

    def _device_params(self):
        p = {k: self.get_parameter(k).value for k in DEVICE}
        p['combined_write'] = bool(self.get_parameter('combined_write').value)
        return p

    # -- lifecycle ------------------------------------------------------------------
    def _refuse(self, why):
        self.get_logger().error('cannot configure: %s' % why)
        self.health.status(ERROR, why)
        self.health.error(why)
        self.ax = {}
        return TransitionCallbackReturn.FAILURE

    def on_configure(self, state):
        """Open the amplifier once, check every axis against it, build the cores."""
        if self.lockstep:
            return self._refuse('mdt693b_driver needs sync_mode realtime (the device runs '
                                'in wall time)')
        try:
            self.ax = {a: Axis(self, a, self._core_params(a), self.period_s,
                               self.axis_health[a], self.bus) for a in self.axes}
        except (ConfigError, ValueError) as exc:
            return self._refuse(str(exc))
        dp = self._device_params()
        try:
            out = DeviceOutput(dp, {a: self.axis_params[a] for a in self.axes})
            info = out.configure()
        except (er.DeviceError, ValueError) as exc:
            for ax in self.ax.values():
                ax.destroy(self)
            return self._refuse(str(exc))
        for a, ax in self.ax.items():
            # the ramp starts where the output is (no jump): a unit re-plugged after a
            # loss, or left at a voltage, comes back at the safe voltages
            out.dev.outputs[a].last_written_v = ax.core.start_at(info['readback_v'][a])
        self.out, self.lost = out, None
        why = out.ramp_safe()
        if why:
            out.close()
            self.out = None
            for ax in self.ax.values():
                ax.destroy(self)
            return self._refuse(why)
        for ax in self.ax.values():
            ax.core.start_at(ax.core.safe)
        out.start()
        self._subs = [subscription(self, Float64, a + '/feedforward_voltage',
                                   lambda msg, a=a: self._on_ff(a, msg), REALTIME_QOS,
                                   self.bus)
                      for a in self.axes]
        self._timer = self.create_timer(self.period_s, self._on_tick,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))
        ident = out.values()['device']
        self.health.resolve()
        self.health.status(OK, 'configured (inactive)')
        refused = out.dev.combined_refused
        if refused:
            self.get_logger().warning('combined_write off: %s (one command a channel)'
                                      % refused)
        self.health.set_values(port=dp['port'], device=ident,
                               device_limit_v=info['device_limit_v'],
                               combined_write=out.dev.combined,
                               combined_refused=refused or '', errors='')
        for ax in self.ax.values():
            ax.health.status(OK, 'configured (inactive): output %g V' % ax.core.v)
            ax.values(out)
        self.get_logger().info('%s on %s: limit switch %g V; %s' % (
            ident, dp['port'], info['device_limit_v'], ', '.join(
                'axis %s on channel %s at %g V' % (a, self.axis_params[a]['channel'],
                                                   info['readback_v'][a])
                for a in self.axes)))
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        """Follow the feedforwards (a lifecycle cycle re-arms a latched watchdog)."""
        for ax in self.ax.values():
            if ax.core.latched:
                ax.core.rearm()
            ax.core.restart_watchdog()
            ax.health.status(OK, 'active')
        self.active = True
        self._set_held(self._any_tripped(), 'activated')
        self.health.status(OK, 'active')
        return super().on_activate(state)

    def on_deactivate(self, state):
        """Stop following the inputs; ramp every axis to its safe voltage."""
        self.active = False
        self._set_held(True, 'deactivated')
        if self._ramp_device():
            return TransitionCallbackReturn.ERROR       # on_error closes the device
        for ax in self.ax.values():
            ax.core.start_at(ax.core.safe)
            ax.pub.publish(Float64(data=ax.core.safe))
            ax.health.status(OK, 'inactive: output %g V' % ax.core.safe)
        if self.out is not None:
            self.out.start()                            # read-back only (nothing pending)
        self.health.status(OK, 'inactive: every axis at its safe voltage')
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        """Close the device; destroy the axes' transport."""
        if self.lost is not None:
            return TransitionCallbackReturn.ERROR
        self._teardown()
        self.health.status(WARN, 'unconfigured')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        """Ramp every axis to its safe voltage, then tear down."""
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
        if self.out is not None:
            self.out.close()
            self.out = None
        for s in self._subs:
            unsubscribe(self, s)
        self._subs = []
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        for ax in self.ax.values():
            ax.health.status(WARN if self.lost is None else ERROR,
                             'unconfigured' if self.lost is None else
                             'device lost: %s' % self.lost)
            ax.destroy(self)
        self.ax = {}
        self.active = False
        self._set_held(True, 'unconfigured')

    def _ramp_device(self):
        """Ramp every axis to its safe voltage; return the loss (one line) or None."""
        out = self.out
        if out is None or self.lost is not None:
            return self.lost
        why = out.ramp_safe()
        if why:
            self.lost = why
            self.health.status(ERROR, 'device lost: %s' % why)
            self.get_logger().error('device lost during the ramp: %s' % why)
        return why

    def close(self):
        """Process exit (SIGINT, no lifecycle shutdown): ramp every axis, shut the port."""
        if getattr(self, 'out', None) is not None:
            self._ramp_device()
            self.out.close()
            self.out = None

    def destroy_node(self):
        """Ramp and close the device (:meth:`close`), then destroy the node."""
        self.close()
        return super().destroy_node()

    # -- the loop -------------------------------------------------------------------
    def _any_tripped(self):
        return any(ax.core.tripped or ax.core.latched for ax in self.ax.values())

    def _set_held(self, held, reason):
        held = bool(held)
        for a, pub in self.pub_held.items():
            if self.held[a] != held:
                self.held[a] = held
                pub.publish(Bool(data=held))
        if reason:
            self.get_logger().debug('drive_held %s (%s)' % (str(held).lower(), reason))

    def _on_ff(self, axis, msg):
        ax = self.ax.get(axis)
        if ax is None or not self.active or self.lost is not None:
            return
        now = time.monotonic()
        cmd = ax.rt.feedforward(msg.data, now, True, sensorless=True)
        if cmd is None:
            return
        core = ax.core
        was = core.tripped
        # any other axis tripped: this one holds too (ramps to its safe voltage)
        others = any(o.core.tripped or o.core.latched for a, o in self.ax.items()
                     if a != axis)
        if others:
            v = core.hold(now, cmd[2])
        else:
            v = core.command(cmd[0], cmd[1], now, cmd[2])
        ax.publish(v, self.out)
        if was and not core.tripped:
            ax.health.status(OK, 'active')
            self.get_logger().info('axis %s: input is back after trip %d'
                                   % (axis, core.watchdog_count))
            self._set_held(self._any_tripped(), 'input is back')

    def _on_tick(self):
        """Every period: the device's health, the read-backs, every axis's watchdog."""
        out = self.out
        if out is None:
            return
        if out.error and self.lost is None:
            self._device_lost(out.error)
            return
        for a, ax in self.ax.items():
            rb = out.readbacks.get(a)
            if rb is not None and rb[1] != ax.rb_t:
                ax.rb_t = rb[1]
                ax.pub_rb.publish(Float64(data=float(rb[0])))
                ax.n_rb += 1
        if self.active:
            self._watchdogs(time.monotonic())
        self._ticks += 1
        if self._ticks % 20 == 0:
            self._values()

    def _watchdogs(self, t):
        tripped = []
        for a, ax in self.ax.items():
            core = ax.core
            before, was_at = core.watchdog_count, core.v
            v = core.tick(t)
            if core.watchdog_count > before:
                tripped.append(a)
                ax.rt.tripped()
            if core.tripped and (v != was_at or ax.last_pub != v):
                ax.publish(v, self.out)
        if not tripped:
            return
        timeout = self.ax[tripped[0]].core.timeout
        msg = ('watchdog: axis %s: no fresh feedforward_voltage for %.3g s: every axis '
               'ramps to its safe voltage' % (', '.join(tripped), timeout))
        self.get_logger().error(msg)
        for a in tripped:
            self.ax[a].health.status(ERROR, msg)
            self.ax[a].health.error(msg)
        self._set_held(True, 'watchdog')
        for a, ax in self.ax.items():          # the others hold as well
            if a not in tripped and not ax.core.tripped:
                ax.core.start_safe_ramp(t)

    def _device_lost(self, reason):
        """Report the loss at once (log, ERROR on /diagnostics) and go to ERROR."""
        self.lost = reason
        text = 'device lost: %s' % reason
        self.get_logger().error(text)
        self.health.status(ERROR, text + '; a configure reconnects')
        self.health.set_values(errors=reason)
        self.health.error(text)
        for ax in self.ax.values():
            ax.health.status(ERROR, text)
        self._set_held(True, 'device lost')
        if self.active:
            self.trigger_deactivate()
        else:
            self.trigger_cleanup()

    def _values(self):
        out = self.out
        if out is None:
            return
        self.health.set_values(command_rate_hz=out.rate_hz(), device_writes=out.writes,
                               last_refusal=out.last_refusal or '')
        for ax in self.ax.values():
            ax.values(out)

    def sent_counts(self):
        """Return published message counts per topic."""
        out = {}
        for a, ax in self.ax.items():
            out[a + '/drive_voltage'] = ax.n_drive
            out[a + '/drive_voltage_readback'] = ax.n_rb
        return out


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(Mdt693bDriverNode, NODE_NAME, args, realtime=lambda node: True)


if __name__ == '__main__':
    sys.exit(main())
