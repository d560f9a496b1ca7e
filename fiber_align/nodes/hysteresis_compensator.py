# SPDX-License-Identifier: Apache-2.0
"""
``hysteresis_compensator``: the feedforward (inverse PI model) as a ROS 2 node.

``ff = Feedforward.step(r)`` (V from m) of :mod:`fiber_align.control.feedforward`, the
exact inverse of the Prandtl-Ishlinskii model, after the optional resonance-suppression shaper
(``shaping``: none | zv | zvd, :mod:`fiber_align.control.shaping`), built by
:func:`fiber_align.control.factory.build_feedforward` for the graph's ``controller`` so
that it is exactly the offline loop's feedforward (``fuzzy``/``pid``: 0 V; ``open-loop``: linear).

When it steps (the shaper and the inverse model advance once per step, so they must
step once per control period):

- ``lockstep``: one ``feedforward_voltage`` (std_msgs/Float64, V) per ``setpoint``
  (std_msgs/Float64, m), so index pairing holds (the setpoint source publishes one
  setpoint per sample);
- ``sensorless`` (graph-wide, the hardware graph): one per setpoint as in lockstep, no
  ``displacement`` subscription;
- ``realtime``: one ``feedforward_voltage`` per ``displacement`` sample (sensor_msgs/
  JointState, newest only; its stamp counts the sample periods), towards the latest
  valid setpoint along the realtime setpoint trajectory
  (:class:`fiber_align.nodes._common.SetpointTrajectory`: rate limit
  ``realtime_setpoint_rate_m_per_s``, 2 mm/s unless the params files set it), stepped
  once per sample it answers. The controller runs the same trajectory. After samples
  this node skipped (it was stalled) it goes on from where it was, one period later,
  rather than over the skipped periods at once: that was a jump of the feedforward by
  the whole stall's move (a 20 ms stall in a 45 um move: peaks of 107-116 um for a
  50 um target; now 58-62 um, the controller's reference having gone on meanwhile;
  ``test_nodes_realtime.py``). While the newest ``drive_voltage`` (newest only) is more
  than ``DRIVE_STALE_PERIODS`` periods old (a stalled driver) the trajectory waits and
  the last feedforward is published again, so that the drive goes on from there (a
  20 ms driver stall mid-move: 50-55 um, 67-85 um before). A setpoint alone
  publishes nothing: a single setpoint from an outside client is thus followed over the
  next samples instead of stopping at the shaper's first tap. The delay compensation
  (``delay_compensation``: a lead over the shaper delay plus one period) predicts one
  period further, the extra delay of the realtime loop (``simulated_actuator``).

Parameters: the model (``thresholds_v``, ``weights_m_per_v``) inline or in
``model_file`` (a params file written by ``PIModel.save``), the shaping, and
``controller`` (graph-wide, see above). Services (std_srvs/Trigger): ``~/reload_model``
reads the model again (e.g. after ``fiber-align identify`` wrote a new file), keeping the
old model when the new one cannot be loaded or inverted; ``~/reset`` restarts the
feedforward at rest at the present position (realtime: the latest measurement; lockstep:
the held setpoint), so that it moves to the held setpoint through the shaper again.
While the driver reports ``drive_held`` true (std_msgs/Bool, latched; realtime), and
after a gap of more than ``_common.MAX_CATCH_UP`` sample periods in its input (it was
stalled and may have missed ``drive_held``), the compensator rests at the measured
position in the same way, so that when
the driver resumes the drive returns to the setpoint through the shaper instead of as a
jump that rings the bending mode.

A NaN, infinite or out-of-range setpoint (outside ``[setpoint_min_m, setpoint_max_m]``)
is rejected with a logged reason and a WARN on ``/diagnostics``; the last valid setpoint
is used in its place (in lockstep exactly one output is still published per input, so
pairing holds) and the actuator stays where it was.
"""

import math
import sys
import time

from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64
from std_srvs.srv import Trigger

from fiber_align.config import ConfigError
from fiber_align.control.factory import build_feedforward, CONTROLLERS
from fiber_align.hysteresis.pi import PIModel
from fiber_align.nodes import _common as c
from fiber_align.nodes._cycle import CycleStats

NODE_NAME = 'hysteresis_compensator'
AREA_FILES = ('compensator.yaml', 'models/compensator_model.yaml')
#: Topics this node publishes (relative names; see ``_common.LocalBus``).
PUBLISHES = ('feedforward_voltage', 'reference')


class HysteresisCompensatorNode(Node):
    """Transport, parameters and the reload service around :class:`Feedforward`."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare parameters (defaults from config/), load the model, wire topics.

        :param bus: the :class:`~fiber_align.nodes._common.LocalBus` of a composed
            process, or ``None``.
        """
        super().__init__(NODE_NAME, **kwargs)
        d = c.node_defaults(NODE_NAME, AREA_FILES)
        self.rate_hz = c.declare(self, d, 'rate_hz', 'control rate (Hz)', 1.0, 20000.0, True)
        self.lockstep = c.declare(self, d, 'sync_mode', 'sample clock', read_only=True,
                                  choices=c.SYNC_MODES) == 'lockstep'
        # sensorless (the hardware graph): no displacement to clock it; one feedforward
        # per setpoint, as in lockstep (the sequencer steps once per power reading)
        sensorless = c.declare(self, d, 'sensorless', 'no displacement sensor: step once '
                               'per setpoint', read_only=True)
        self.per_setpoint = self.lockstep or bool(sensorless)
        diag = c.declare(self, d, 'diagnostics_period_s', '/diagnostics period (s)', 0.01,
                         60.0, True)
        self.sp_lo = c.declare(self, d, 'setpoint_min_m', 'lowest accepted setpoint (m)',
                               -1e-3, 1e-3, True)
        self.sp_hi = c.declare(self, d, 'setpoint_max_m', 'highest accepted setpoint (m)',
                               -1e-3, 1e-3, True)
        c.declare(self, d, 'controller', 'control law (as in fiber-align simulate)',
                  read_only=True, choices=CONTROLLERS)
        rate = c.declare_graph(self, d, 'realtime_setpoint_rate_m_per_s',
                               c.REALTIME_SETPOINT_RATE_M_PER_S,
                               'realtime: rate limit of the setpoint trajectory (m/s); '
                               '<= 0: none', -1.0, 10.0, True)
        c.declare_priority(self, d)
        self.traj = c.SetpointTrajectory(1.0 / self.rate_hz, rate)
        c.declare(self, d, 'model_file', 'PI model params file; empty: the inline model')
        c.declare(self, d, 'model_source', 'where the inline model comes from')
        c.declare(self, d, 'thresholds_v', 'PI play-operator thresholds (V)')
        c.declare(self, d, 'weights_m_per_v', 'PI weights (m/V)')
        self.shaping = c.declare_shaping(self, d)
        self.open_loop_gain = c.declare(self, d, 'open_loop_gain_v_per_m',
                                        'linear feedforward gain (V/m)', 0.0, 1e9, True)
        self.slack = c.slack_of(bus)
        self.pub = c.Pub(self, Float64, 'feedforward_voltage', c.CONTROL_QOS, bus,
                         slack=self.slack)
        # the accepted setpoint for the controller (one consumer of ``setpoint``)
        self.pub_ref = c.Pub(self, Float64, 'reference', c.CONTROL_QOS, bus,
                             latched=not self.lockstep)
        self._msg = Float64()
        self._ref_msg = Float64()
        self.n_ref = 0
        # lockstep: transient local, so the first setpoint of the source (published as
        # soon as it matched) is not lost if this reader matched a moment later
        c.subscription(self, Float64, 'setpoint', self._on_setpoint,
                       c.LOCKSTEP_QOS if self.lockstep else c.SETPOINT_QOS, bus)
        self.held = False               # realtime: the driver holds its output
        if not self.per_setpoint:
            c.subscription(self, JointState, 'displacement', self._on_sample,
                           c.REALTIME_QOS, bus)
            c.subscription(self, Bool, 'drive_held', self._on_held, c.LATCHED_QOS, bus)
            c.subscription(self, Float64, 'drive_voltage', self._on_drive, c.REALTIME_QOS,
                           bus)
        self.t_drive = None             # realtime: wall time (s) of the newest drive
        self.ff_last = 0.0              # realtime: the feedforward last published (V)
        self.create_service(Trigger, '~/reload_model', self._on_reload)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.health = c.Health(self, diag, slack=self.slack)
        self.health.cycle = CycleStats(self.rate_hz)
        self.r = 0.0
        self.y_latest = 0.0
        self.n_ff = 0
        self.rejected = 0
        self.ff = self.build()
        self.health.status(c.OK, 'ready (%s)' % self.get_parameter('controller').value)
        self.get_logger().info('compensator ready: %s, shaping %s, model %s'
                               % (self.get_parameter('controller').value,
                                  self.get_parameter('shaping').value, self.model_name()))

    def model_name(self):
        """Return where the model comes from (file path or ``inline``)."""
        return self.get_parameter('model_file').value or 'inline'

    def load_model(self):
        """Return the PI model of the parameters (or of ``model_file``)."""
        path = self.get_parameter('model_file').value
        if path:
            return PIModel.load(path)
        return PIModel([float(x) for x in self.get_parameter('thresholds_v').value],
                       [float(x) for x in self.get_parameter('weights_m_per_v').value])

    def build(self):
        """Return a fresh :class:`Feedforward` (V from m) for the parameters."""
        comp = dict(self.shaping, open_loop_gain_v_per_m=self.open_loop_gain)
        ff = build_feedforward(self.get_parameter('controller').value, comp,
                               self.load_model(), c.design_model(self.shaping), self.rate_hz)
        if not self.per_setpoint:
            c.extend_lead(ff, 1.0 / self.rate_hz)    # the realtime loop's extra period
        return ff

    def _on_reload(self, request, response):
        """Reload the model; keep the old one if the new one fails."""
        try:
            ff = self.build()
        except (ConfigError, ValueError, OSError, KeyError) as exc:
            response.success = False
            response.message = 'kept the old model: %s' % exc
            self.get_logger().error(response.message)
            self.health.warn(response.message)
            return response
        ff.start_at(self.r)   # the new inverse settled at the present setpoint
        self.ff = ff
        response.success = True
        response.message = 'model reloaded from %s' % self.model_name()
        self.get_logger().info(response.message)
        return response

    def _on_setpoint(self, msg):
        """
        Take the user's setpoint (m): this node is its only consumer.

        An accepted setpoint is passed on as ``reference`` for the controller, so the
        feedforward and the feedback always follow the same reference (a setpoint either
        reaches the whole loop or none of it). Lockstep passes one ``reference`` per
        setpoint (the held one in place of a rejected one, so pairing holds).
        """
        why = c.check_setpoint(msg.data, self.sp_lo, self.sp_hi)
        if why is None:
            self.r = float(msg.data)
        else:
            self.rejected += 1
            text = 'rejected %s; holding %.6g m' % (why, self.r)
            self.get_logger().warn(text)
            self.health.warn(text)
            self._update_values()
            if not self.per_setpoint:
                return
        ref = self._ref_msg
        ref.data = self.r
        self.pub_ref.publish(ref)
        self.n_ref += 1
        if self.per_setpoint:
            self._publish(self.ff.step(self.r))

    def _on_sample(self, msg):
        """Realtime: step the feedforward; count the sample-to-feedforward latency (s)."""
        self._step_sample(msg)
        st, cyc = msg.header.stamp, self.health.cycle
        ns = c.stamp_ns(st)
        cyc.record((time.time_ns() - ns) * 1e-9, cyc.index(ns))

    def _step_sample(self, msg):
        """Step the feedforward one period (a gap over MAX_CATCH_UP: rest, see below)."""
        if len(msg.position):
            self.y_latest = msg.position[0]
        n = self.traj.periods(msg.header.stamp)
        if self.held or n > c.MAX_CATCH_UP:
            # the driver holds its output (or this node was stalled and cannot know):
            # rest at the present position, so that after the resume the feedforward
            # returns to the setpoint along the trajectory
            y = self._present()
            self.traj.reset(y)
            self._publish(self.ff.start_at(y))
            return
        t_drive = self.t_drive
        if t_drive is not None and \
                time.monotonic() - t_drive > c.DRIVE_STALE_PERIODS / self.rate_hz:
            # the driver is stalled (the loop is open): the trajectory waits, so that
            # the drive goes on from here when the driver does, not by the stall's move
            self._publish(self.ff_last)
            return
        # one period whatever the gap (docstring): a stall delays the move, never jumps it
        self._publish(self.ff.step(self.traj.advance(self.r, 1)[0]))

    def _present(self):
        """Return the latest measured position (m), at least 0 m."""
        y = self.y_latest
        return max(0.0, float(y)) if math.isfinite(y) else 0.0

    def _on_held(self, msg):
        """Realtime: the driver holds (true) or passes (false) its output."""
        self.held = bool(msg.data)

    def _on_drive(self, msg):
        """Realtime: note when the newest drive command arrived (wall time)."""
        self.t_drive = time.monotonic()

    def _on_reset(self, request, response):
        """Restart the feedforward at rest at the present position (m)."""
        y = max(0.0, self.r) if self.per_setpoint else self._present()
        self.ff.start_at(y)
        self.traj.reset(y)
        response.success = True
        response.message = 'feedforward restarted at %.6g m' % y
        self.get_logger().info(response.message)
        return response

    def _publish(self, v):
        """Publish the feedforward voltage ``v`` (V)."""
        self.ff_last = v
        msg = self._msg
        msg.data = float(v)
        self.pub.publish(msg)
        self.n_ff += 1
        if self.n_ff % 500 == 0:
            self._update_values()

    def _update_values(self):
        """Report counts and the held setpoint (m) on ``/diagnostics``."""
        self.health.set_values(**{'sent.feedforward_voltage': self.n_ff,
                                  'rejected_setpoints': self.rejected,
                                  'setpoint_m': self.r})

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'feedforward_voltage': self.n_ff, 'reference': self.n_ref}


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    stop = c.init(args)
    node = None
    try:
        node = HysteresisCompensatorNode()
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
