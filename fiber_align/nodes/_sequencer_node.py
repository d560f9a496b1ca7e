# SPDX-License-Identifier: Apache-2.0
"""
What the 1-D and the 2-D sequencer nodes share: services, state topic, driver health.

A node that mixes :class:`SequencerNode` in has ``seq`` (the pure core: ``align``,
``release``, ``switch(on)`` returning ``(ok, message)``, ``status()``), ``health``
(:class:`~fiber_align.nodes._common.Health`) and implements ``_publish_state()`` (with
:meth:`SequencerNode._publish_status`) and ``_driver_report(name, ok)``.
"""

import json

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from fiber_align.alignment.states import FAULT
from fiber_align.nodes import _common as c

#: ``alignment_state``: reliable, transient local, depth 1 (a late joiner gets the state).
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)


class SequencerNode:
    """Mixin of the sequencer nodes (see the module docstring)."""

    def _serve(self):
        """Create ``alignment_state``, the services and the ``/diagnostics`` reader."""
        from diagnostic_msgs.msg import DiagnosticArray
        self.pub_state = self.create_publisher(String, 'alignment_state', STATE_QOS)
        self.n_state = 0
        self._last = None
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, c.DIAG_QOS)
        self.create_service(Trigger, 'align', self._on_align)
        self.create_service(Trigger, 'release', self._on_release)
        self.create_service(SetBool, 'switch', self._on_switch)

    def _publish_status(self, s, **values):
        """Publish status ``s`` (dict) when its state or fault changed; health, log."""
        key = (s['state'], s['fault_reason'])
        if key == self._last:
            return
        self._last = key
        self.pub_state.publish(String(data=json.dumps(s)))
        self.n_state += 1
        if s['state'] == FAULT:
            self.health.status(c.ERROR, 'FAULT: %s' % s['fault_reason'])
            self.get_logger().error('FAULT: %s' % s['fault_reason'])
        else:
            self.health.status(c.OK, s['state'])
            self.get_logger().info('state %s' % s['state'])
        self.health.set_values(state=s['state'], fault_reason=s['fault_reason'],
                               peak_samples=s['peak_samples'], **values)

    def _on_diag(self, msg):
        for st in msg.status:
            level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
            self._driver_report(st.name, level < c.ERROR)

    def _answer(self, response, result):
        response.success, response.message = bool(result[0]), str(result[1])
        self._publish_state()
        return response

    def _on_align(self, request, response):
        return self._answer(response, self._command_align())

    def _command_align(self):
        return self.seq.align()

    def _on_release(self, request, response):
        return self._answer(response, self.seq.release())

    def _on_switch(self, request, response):
        return self._answer(response, self.seq.switch(bool(request.data)))
