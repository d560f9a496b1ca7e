# SPDX-License-Identifier: Apache-2.0
"""
What the 1-D and the 2-D sequencer nodes share: services, state topic, driver state.

``/diagnostics``: OK in IDLE, SEARCHING, PEAKING, TRACKING, RELEASING; WARN with the
reason in HELD (the driver holds its output); ERROR with the reason in FAULT.

The drivers' state (:meth:`SequencerNode._watch_drivers`): for each driver (a name
relative to the node's namespace, e.g. ``actuator_driver`` or ``x/actuator_driver``) its
latched ``drive_held`` (std_msgs/Bool; the topic in the driver's namespace), its
``<driver>/transition_event`` (lifecycle_msgs/TransitionEvent) and its ``/diagnostics``
status are turned into the core's ``driver_held``, ``driver_lifecycle`` and
``driver_diagnostics`` calls (the rules are the core's,
:class:`fiber_align.alignment.driver_state.DriverState`); the last ``drive_held`` writer
unmatched (its ``matched`` event: the driver's process ended; a clean exit says so at
once, a killed one after its DDS lease) and still without a writer
:data:`GONE_GRACE_S` later is ``driver_gone``. A call that changes the
state publishes it at once.

A node that mixes :class:`SequencerNode` in has ``seq`` (the pure core: ``align``,
``release``, ``switch(on)`` returning ``(ok, message)``, ``status()`` and the driver
calls above), ``health`` (:class:`~fiber_align.nodes.ros.diagnostics.Health`) and
implements ``_publish_state()`` (with :meth:`SequencerNode._publish_status`).
"""

import json

from lifecycle_msgs.msg import TransitionEvent
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from std_msgs.msg import Bool, String
from std_srvs.srv import SetBool, Trigger

from fiber_align.alignment.states import FAULT, HELD
from fiber_align.config import load_params
from fiber_align.nodes.ros.bus import subscription
from fiber_align.nodes.ros.diagnostics import ERROR, OK, WARN
from fiber_align.nodes.ros.params import declare
from fiber_align.nodes.ros.qos import DIAG_QOS, LATCHED_QOS, STATE_QOS, TRANSITION_EVENT_QOS

#: s from a driver's last ``drive_held`` writer unmatched to "gone" (``_gone_later``).
GONE_GRACE_S = 0.05


class SequencerNode:
    """Mixin of the sequencer nodes (see the module docstring)."""

    def _serve(self):
        """Create ``alignment_state``, the services and the ``/diagnostics`` reader."""
        from diagnostic_msgs.msg import DiagnosticArray
        self.pub_state = self.create_publisher(String, 'alignment_state', STATE_QOS)
        self.n_state = 0
        self._last = None
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, DIAG_QOS)
        self.create_service(Trigger, 'align', self._on_align)
        self.create_service(Trigger, 'release', self._on_release)
        self.create_service(SetBool, 'switch', self._on_switch)

    def _declare_core(self, defaults, config_file, config_node):
        """
        Declare every key of the core's params-file section, read-only; return them.

        :param defaults: the node's defaults (``node_defaults``).
        :param config_file: the core's file in ``config/`` (its section is the one source
            of the core's keys).
        :returns: ``{name: value}`` for the core's constructor (SI).
        """
        return {name: declare(self, defaults, name, 'sequencer parameter (SI, see %s)'
                              % config_file, read_only=True)
                for name in load_params(config_file, config_node)}

    def _watch_drivers(self, drivers, bus, lifecycle=None):
        """
        Feed what each driver publishes to the core (module docstring).

        :param drivers: ``{core name: topic prefix}``: the core's name of each driver and
            the namespace of its topics relative to this node's ('' or ``x/``).
        :param bus: the process's :class:`~fiber_align.nodes.ros.bus.LocalBus` or None.
        :param lifecycle: ``{core name: lifecycle node}`` where a driver's transitions are
            another node's (one amplifier node serving several axes); default its own.
        """
        ns = self.get_namespace().rstrip('/')
        self._driver_diag = {'%s/%s' % (ns, name): name for name in drivers}
        for name, prefix in drivers.items():
            topic = prefix + 'drive_held'

            def held(msg, n=name):
                self._driver_news(self.seq.driver_held(bool(msg.data), n))

            def matched(info, n=name, t=topic):
                # the last drive_held writer unmatched: the driver's process ended
                if info.current_count == 0 and info.current_count_change < 0:
                    self._gone_later(n, self.resolve_topic_name(t))
            if bus is not None and bus.local(self, topic):
                subscription(self, Bool, topic, held, LATCHED_QOS, bus)   # same process
            else:
                self.create_subscription(
                    Bool, topic, held, LATCHED_QOS,
                    event_callbacks=SubscriptionEventCallbacks(matched=matched))
            self.create_subscription(
                TransitionEvent, (lifecycle or {}).get(name, name) + '/transition_event',
                lambda msg, n=name: self._driver_news(
                    self.seq.driver_lifecycle(msg.goal_state.label, n)),
                TRANSITION_EVENT_QOS)

    def _gone_later(self, name, topic):
        """
        Call the driver ``name`` gone after :data:`GONE_GRACE_S` if ``topic`` has no writer.

        The grace lets a graph that stops as a whole (every process SIGINTed at once) end
        this node's spin first: its state at the stop stays what it was.
        """
        box = []

        def fire():
            self.destroy_timer(box[0])
            if self.count_publishers(topic) == 0:
                self._driver_news(self.seq.driver_gone(name))
        box.append(self.create_timer(GONE_GRACE_S, fire,
                                     clock=Clock(clock_type=ClockType.STEADY_TIME)))

    def _driver_news(self, acted):
        if acted:
            self._publish_state()

    def _publish_status(self, s, **values):
        """Publish status ``s`` (dict) when its state or fault changed; health, log."""
        key = (s['state'], s['fault_reason'])
        if key == self._last:
            return
        self._last = key
        self.pub_state.publish(String(data=json.dumps(s)))
        self.n_state += 1
        if s['state'] == FAULT:
            self.health.status(ERROR, 'FAULT: %s' % s['fault_reason'])
            self.get_logger().error('FAULT: %s' % s['fault_reason'])
        elif s['state'] == HELD:
            self.health.status(WARN, 'HELD: %s' % s.get('hold_reason', ''))
            self.get_logger().warning('HELD: %s' % s.get('hold_reason', ''))
        else:
            self.health.status(OK, s['state'])
            self.get_logger().info('state %s' % s['state'])
        self.health.set_values(state=s['state'], fault_reason=s['fault_reason'],
                               peak_samples=s['peak_samples'], **values)

    def _on_diag(self, msg):
        for st in msg.status:
            name = self._driver_diag.get(st.name)
            if name is not None:
                level = st.level[0] if isinstance(st.level, (bytes, bytearray)) \
                    else int(st.level)
                self._driver_news(self.seq.driver_diagnostics(level < ERROR, name))

    def _answer(self, response, result):
        response.success, response.message = bool(result[0]), str(result[1])
        self._publish_state()
        return response

    def _on_align(self, request, response):
        return self._answer(response, self._command_align())

    def _command_align(self):
        result = self.seq.align()
        if result[0] and hasattr(self, 'align_sample'):
            # the multi-axis nodes: the index of the update the command acted before
            self.align_sample = self.n
        return result

    def _on_release(self, request, response):
        return self._answer(response, self.seq.release())

    def _on_switch(self, request, response):
        return self._answer(response, self.seq.switch(bool(request.data)))
