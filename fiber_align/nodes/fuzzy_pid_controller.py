# SPDX-License-Identifier: Apache-2.0
"""
``fuzzy_pid_controller``: the feedback law of the control core as a ROS 2 node.

Runs once per ``displacement`` sample (sensor_msgs/JointState, m): ``fb_k =
controller.step(r_k, y_k)`` with the law the factory builds for the graph's
``controller`` (composite and fuzzy: fuzzy PID; composite-pid and pid: PID; feedforward
and open-loop: 0 V), exactly what the offline loop computes. ``r`` is ``reference``
(std_msgs/Float64, m): the setpoint the compensator accepted (the only consumer of
``setpoint``), latched so a restarted controller has it at once. Publishes
``feedback_voltage`` (V) and ``controller_state`` (Float64MultiArray, labelled dims in SI;
every ``controller_state_every`` samples). ``~/reset``
(std_srvs/Trigger) clears the integral and filters. Lockstep pairs the i-th displacement
with the i-th reference; realtime steps on the newest sample along the realtime setpoint
trajectory, with one period more delay than lockstep, and parks (0 V, no integral,
reference model at the measured position) while ``drive_held`` is true or the drive is
stale, so every resume is bumpless. Every parameter of ``config/controller.yaml`` is a
ROS parameter; gains, scale factors and limits change live (checked, state kept). The
full behaviour, with the reasons: docs/ros_interface.md, section "fuzzy_pid_controller".
"""

import math
import sys
import time

from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, Float64MultiArray, MultiArrayDimension
from std_srvs.srv import Trigger

from fiber_align.config import ConfigError, flatten, unflatten
from fiber_align.control.factory import build_controller, check_param, CONTROLLERS
from fiber_align.control.factory import PARAM_RANGES
from fiber_align.nodes import _common as c
from fiber_align.nodes._cycle import CycleStats

NODE_NAME = 'fuzzy_pid_controller'
AREA_FILES = ('controller.yaml',)
MODES = CONTROLLERS
#: Realtime: the controller holds its output while the newest ``drive_voltage`` is older
#: than this many periods (the loop is open: nothing may wind up); one value with the
#: compensator's.
DRIVE_STALE_PERIODS = c.DRIVE_STALE_PERIODS
STATE_LABELS = ('error_m', 'error_rate_m_per_s', 'kp_v_per_m', 'ki_v_per_m_s',
                'kd_v_s_per_m', 'output_v')
GRAPH_KEYS = ('controller', 'sync_mode', 'rate_hz', 'diagnostics_period_s', 'setpoint_min_m',
              'setpoint_max_m', 'realtime_setpoint_rate_m_per_s', 'controller_state_every',
              'realtime_priority', 'lock_memory')
#: Topics this node publishes (relative names; see ``_common.LocalBus``).
PUBLISHES = ('feedback_voltage', 'controller_state')


def make_controller(controller, params, rate_hz, shaping, surface=None):
    """
    Build the feedback law exactly as the offline simulation does.

    :param controller: a controller name of ``fiber-align simulate`` (composite,
        composite-pid, fuzzy, pid, feedforward, open-loop); the last two have no feedback.
    :param params: controller parameters (nested, SI).
    :param rate_hz: control rate (Hz).
    :param shaping: the reference shaping and design file (the compensator's values,
        :func:`~fiber_align.nodes._common.declare_shaping`).
    :param surface: the fuzzy surface of the controller it replaces (reused if it fits).
    :returns: an object with ``step(r, y) -> V`` or ``None``.
    """
    return build_controller(controller, params, shaping, c.design_model(shaping), rate_hz,
                            surface)


class FuzzyPidControllerNode(Node):
    """Transport and parameters around the fuzzy PID of the control core."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare parameters (defaults from config/), build the controller, wire topics.

        :param bus: the :class:`~fiber_align.nodes._common.LocalBus` of a composed
            process, or ``None``.
        """
        super().__init__(NODE_NAME, **kwargs)
        d = c.node_defaults(NODE_NAME, AREA_FILES)
        self.mode = c.declare(self, d, 'controller', 'control law (as in fiber-align simulate)',
                              choices=MODES)
        self.rate_hz = c.declare(self, d, 'rate_hz', 'control rate (Hz)', 1.0, 20000.0, True)
        self.lockstep = c.declare(self, d, 'sync_mode', 'message pairing', read_only=True,
                                  choices=c.SYNC_MODES) == 'lockstep'
        diag = c.declare(self, d, 'diagnostics_period_s', '/diagnostics period (s)', 0.01,
                         60.0, True)
        self.sp_lo = c.declare(self, d, 'setpoint_min_m', 'lowest accepted setpoint (m)',
                               -1e-3, 1e-3)
        self.sp_hi = c.declare(self, d, 'setpoint_max_m', 'highest accepted setpoint (m)',
                               -1e-3, 1e-3)
        rate = c.declare_graph(self, d, 'realtime_setpoint_rate_m_per_s',
                               c.REALTIME_SETPOINT_RATE_M_PER_S,
                               'realtime: rate limit of the setpoint trajectory (m/s); '
                               '<= 0: none', -1.0, 10.0, True)
        c.declare_priority(self, d)
        self.traj = c.SetpointTrajectory(1.0 / self.rate_hz, rate)
        self.state_every = c.declare(self, d, 'controller_state_every',
                                     'publish controller_state every N samples (1); 0: off',
                                     0, 1000000)
        self.shaping = c.declare_shaping(self, d)   # the reference model's (SHARED)
        core = {k: v for k, v in d.items() if k not in GRAPH_KEYS and k not in c.SHARED}
        self.core_names = []
        for name, value in flatten(core).items():
            key = name.split('.')[-1]
            lo, hi = PARAM_RANGES.get(key, (None, None))
            scalar = isinstance(value, (int, float)) and not isinstance(value, bool)
            c.declare(self, {name: value}, name, 'controller parameter (SI, see '
                      'controller.yaml)', lo if scalar else None, hi if scalar else None)
            self.core_names.append(name)
        self.ctl = self._make(self.mode, self._core_params())
        self.add_on_set_parameters_callback(self._on_set)

        self.slack = c.slack_of(bus)
        self.pub_fb = c.Pub(self, Float64, 'feedback_voltage', c.CONTROL_QOS, bus,
                            slack=self.slack)
        self.pub_state = c.Pub(self, Float64MultiArray, 'controller_state', c.CONTROL_QOS,
                               bus)
        self._fb_msg = Float64()
        self._state_msg = Float64MultiArray()
        self._state_msg.layout.dim = [MultiArrayDimension(label=lab, size=1, stride=1)
                                      for lab in STATE_LABELS]
        c.subscription(self, JointState, 'displacement', self._on_disp,
                       c.sample_qos(self.lockstep), bus)
        # the reference is the setpoint the compensator accepted (it is the only consumer
        # of ``setpoint``); realtime reads it latched, so a restarted controller has it
        c.subscription(self, Float64, 'reference', self._on_setpoint,
                       c.LOCKSTEP_QOS if self.lockstep else c.REFERENCE_LATCHED_QOS, bus)
        self.held = False               # realtime: the driver holds its output
        self.t_drive = None             # realtime: wall time (s) of the newest drive
        if not self.lockstep:
            c.subscription(self, Bool, 'drive_held', self._on_held, c.LATCHED_QOS, bus)
            c.subscription(self, Float64, 'drive_voltage', self._on_drive, c.REALTIME_QOS,
                           bus)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.health = c.Health(self, diag, slack=self.slack)
        self._stamp_ns = 0              # realtime: stamp (ns) of the sample being answered
        self.wired = self.lockstep      # realtime: the driver and compensator are heard
        if not self.lockstep:
            self.health.cycle = CycleStats(self.rate_hz)
        self.r = 0.0
        self.r_prev = 0.0               # realtime: latest setpoint at the previous sample
        self.has_setpoint = False       # realtime: feedback off until the first setpoint
        self.y_latest = 0.0
        self.sp_q = []
        self.y_q = []
        self.n_fb = 0
        self.n_state = 0
        self.rejected = 0
        self.n_y = 0
        self.health.status(c.OK, 'running (%s)' % self.mode if self.lockstep else
                           'waiting for a setpoint: feedback off (%s)' % self.mode)
        self.get_logger().info('controller ready: mode %s at %g Hz, %s pairing'
                               % (self.mode, self.rate_hz,
                                  'index' if self.lockstep else 'latest-setpoint'))

    # -- parameters -----------------------------------------------------------------
    def _make(self, mode, params):
        """Build the feedback law; realtime: its reference model's lead covers one more T."""
        ctl = make_controller(mode, params, self.rate_hz, self.shaping,
                              getattr(getattr(self, 'ctl', None), 'surface', None))
        if ctl is not None and not self.lockstep:
            c.extend_lead(getattr(ctl, 'reference_filter', None), 1.0 / self.rate_hz)
        return ctl

    def _core_params(self, changes=None):
        flat = {n: self.get_parameter(n).value for n in self.core_names}
        flat.update(changes or {})
        return unflatten(flat)

    def _on_set(self, params):
        """Validate a live update; rebuild the controller and keep its state."""
        changes = {}
        mode = self.mode
        for p in params:
            if p.name in ('setpoint_min_m', 'setpoint_max_m'):
                res = c.check_parameters([p], {p.name: (-1e-3, 1e-3)})
                if not res.successful:
                    return res
            elif p.name == 'controller':
                if p.value not in MODES:
                    return SetParametersResult(successful=False, reason='controller=%r: must be '
                                               'one of %s' % (p.value, ', '.join(MODES)))
                mode = p.value
            elif p.name in self.core_names:
                why = check_param(p.name, p.value)
                if why:
                    return SetParametersResult(successful=False, reason=why)
                changes[p.name] = p.value
        if not changes and mode == self.mode:
            for p in params:
                if p.name == 'setpoint_min_m':
                    self.sp_lo = float(p.value)
                elif p.name == 'setpoint_max_m':
                    self.sp_hi = float(p.value)
            return SetParametersResult(successful=True)
        try:
            new = self._make(mode, self._core_params(changes))
        except (ConfigError, ValueError, KeyError, TypeError) as exc:
            return SetParametersResult(successful=False, reason='rejected: %s' % exc)
        if new is not None and self.ctl is not None and mode == self.mode:
            old, npid = self.ctl.pid, new.pid
            npid.integral, npid.deriv, npid.e_prev, npid.u = (
                old.integral, old.deriv, old.e_prev, old.u)
            new.u = self.ctl.u
            if getattr(self.ctl, 'reference_filter', None) is not None:
                new.reference_filter = self.ctl.reference_filter
        self.ctl = new
        self.mode = mode
        for p in params:
            if p.name == 'setpoint_min_m':
                self.sp_lo = float(p.value)
            elif p.name == 'setpoint_max_m':
                self.sp_hi = float(p.value)
        self.get_logger().info('parameters updated: %s' % ', '.join(p.name for p in params))
        return SetParametersResult(successful=True)

    # -- messages -------------------------------------------------------------------
    def _on_reset(self, request, response):
        """Clear the controller's integral and filters."""
        if self.ctl is not None:
            self.ctl.reset()
            if not self.lockstep:
                self._park()
        response.success = True
        response.message = 'controller reset'
        return response

    def _park(self):
        """Realtime: rest at the latest measured position (reference model, trajectory)."""
        y = self.y_latest
        y = max(0.0, float(y)) if math.isfinite(y) else 0.0
        self.traj.reset(y)
        self.r_prev = y         # the setpoint one sample old
        rf = getattr(self.ctl, 'reference_filter', None)
        if rf is None:
            return
        rf.reset()
        if rf.shaper is not None:
            rf.shaper.reset(y)
        if rf.lead is not None:
            rf.lead.reset(y)
        rf.x, rf.xd = y, 0.0

    def _valid(self, value):
        """Return ``value`` as a float (m), or ``None`` after reporting why it is rejected."""
        why = c.check_setpoint(value, self.sp_lo, self.sp_hi)
        if why is None:
            return float(value)
        self.rejected += 1
        msg = 'rejected %s; holding %.6g m' % (why, self.r)
        self.get_logger().warn(msg)
        self.health.warn(msg)
        self.health.set_values(rejected_setpoints=self.rejected, setpoint_m=self.r)
        return None

    def _on_setpoint(self, msg):
        r = self._valid(msg.data)
        if self.lockstep:
            self.r = self.r if r is None else r
            self.sp_q.append(self.r)
            self._pair()
        elif r is not None:
            if not self.has_setpoint:
                # first setpoint of this controller: start from rest at the present
                # position, which is also the "setpoint one sample old"
                self.has_setpoint = True
                if self.ctl is not None:
                    self.ctl.reset()
                self._park()
                self.health.status(c.OK, 'running (%s)' % self.mode)
            self.r = r

    def _on_held(self, msg):
        """Realtime: the driver holds (true) or passes (false) its output."""
        held = bool(msg.data)
        if held and not self.held and self.ctl is not None:
            self.ctl.reset()            # nothing may wind up while the output is held
        self.held = held

    def _on_drive(self, msg):
        """Realtime: note when the newest drive command arrived (wall time)."""
        self.t_drive = time.monotonic()

    def _on_disp(self, msg):
        y = msg.position[0] if len(msg.position) else math.nan
        self.n_y += 1
        if self.lockstep:
            self.y_q.append(y)
            self._pair()
            return
        self.y_latest = y
        if not self.wired and not self._wire():
            return
        st = msg.header.stamp
        self._stamp_ns = c.stamp_ns(st)
        n = self.traj.periods(st)
        if n > c.MAX_CATCH_UP and self.ctl is not None:
            self.ctl.reset()            # stalled: the integral is stale (docstring)
            self._park()
            n = 1
        if self.held or not self.has_setpoint:
            if self.held:
                # park at the present position (integral already cleared): after the
                # driver resumes, trajectory and reference model start from here
                self._park()
            self._publish(0.0, math.nan, 0.0, (0.0, 0.0, 0.0))
            return
        t_drive = self.t_drive
        if t_drive is None or time.monotonic() - t_drive > DRIVE_STALE_PERIODS / self.rate_hz:
            # no fresh drive: the loop is open (driver stalled or not publishing): hold
            # the output and integrate nothing; the trajectory and the reference model
            # wait, as the compensator's trajectory does, so that the drive goes on
            # from where it stopped instead of jumping by the stall's move
            u = self.ctl.u if self.ctl is not None else 0.0
            self._publish(u, math.nan, 0.0, getattr(self.ctl, 'gains', (0.0, 0.0, 0.0)))
            return
        # realtime: the trajectory's value one sample old for each period since the last
        # sample (one period of delay, see the docstring); periods whose sample this node
        # skipped advance the reference model only
        seq = [self.r_prev] + self.traj.advance(self.r, n)
        self.r_prev = seq[-1]
        rf = getattr(self.ctl, 'reference_filter', None)
        if rf is not None:
            for r in seq[:-2]:
                rf.step(r)
        self._step(seq[-2], y)

    def _wire(self):
        """Realtime: True once the driver and compensator are heard (then start parked)."""
        # a restarted controller that ran before its drive_voltage, drive_held and
        # reference readers matched wound up blind to a held driver (two hogs: 102 um)
        self.wired = all(self.count_publishers(self.resolve_topic_name(t)) > 0
                         for t in ('drive_voltage', 'drive_held', 'reference'))
        if self.wired and self.ctl is not None:
            self.ctl.reset()
            self._park()
        return self.wired

    def _pair(self):
        while self.sp_q and self.y_q:
            self._step(self.sp_q.pop(0), self.y_q.pop(0))

    def _step(self, r, y):
        if self.ctl is None:
            fb, e, de, gains = 0.0, r - y, 0.0, (0.0, 0.0, 0.0)
        else:
            fb = self.ctl.step(r, y)
            e = r - y
            de = self.ctl.pid.deriv
            gains = self.ctl.gains
        self._publish(fb, e, de, gains)

    def _publish(self, fb, e, de, gains):
        """Publish the feedback (V) and the controller state (SI)."""
        msg = self._fb_msg
        msg.data = float(fb)
        self.pub_fb.publish(msg)
        self.n_fb += 1
        cyc = self.health.cycle
        if cyc is not None:             # realtime: sample-to-feedback latency
            cyc.record((time.time_ns() - self._stamp_ns) * 1e-9, cyc.index(self._stamp_ns))
        if self.state_every and self.n_fb % self.state_every == 0:
            st = self._state_msg
            st.data = [float(e), float(de), float(gains[0]), float(gains[1]),
                       float(gains[2]), float(fb)]
            self.pub_state.publish(st)
            self.n_state += 1
        if self.n_fb % 500 == 0:
            self.health.set_values(**{'sent.feedback_voltage': self.n_fb,
                                      'sent.controller_state': self.n_state,
                                      'rejected_setpoints': self.rejected,
                                      'setpoint_m': self.r, 'mode': self.mode})

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'feedback_voltage': self.n_fb, 'controller_state': self.n_state}


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    stop = c.init(args)
    node = None
    try:
        node = FuzzyPidControllerNode()
        c.spin(node, realtime=not node.lockstep, priority=c.node_priority(node), stop=stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except c.NODE_ERRORS as exc:
        return c.refuse(NODE_NAME, exc)
    finally:
        c.finish(node)
    return 0


if __name__ == '__main__':
    sys.exit(main())
