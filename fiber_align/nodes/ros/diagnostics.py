# SPDX-License-Identifier: Apache-2.0
"""
A node's health on ``/diagnostics`` (diagnostic_msgs).

:class:`Health` is the stand-in for ``diagnostic_updater.Updater`` (not in a pip install
of ROS 2), with its shape: ``add(name, fn)`` tasks, each ``fn(stat)`` filling a
:class:`~fiber_align.control.health.StatusWrapper` (``summary(level, message)``,
``add(key, value)``), the node's own ``summary(level, message)`` and ``force_update()``;
swap it for the updater when installed. The status itself, its levels (``OK``, ``WARN``,
``ERROR``, ``STALE``), latch and conditions: :mod:`fiber_align.control.health`.
"""

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from fiber_align.control.health import ERROR, LEVELS, OK, STALE, Status, WARN
from fiber_align.graph.endpoints import foreign_publishers, node_fqn, suspect_topics
from fiber_align.graph.endpoints import type_name
from fiber_align.nodes.ros.qos import DIAG_QOS

#: the levels, for the nodes that import them with :class:`Health`
__all__ = ('endpoint_node_name', 'ERROR', 'Health', 'LEVELS', 'OK', 'report_refusals',
           'STALE', 'WARN')


def report_refusals(node, health):
    """
    Log every parameter change ``node`` refuses and report it on ``health`` (a WARN).

    Every change (``ros2 param set``, a client, in-process) ends in
    ``Node.set_parameters_atomically`` or ``Node.set_parameters``: a range, a read-only or
    undeclared name and the node's own check alike. Once per node (its first health).
    """
    if getattr(node, '_fiber_align_refusals', None) is not None:
        return
    atomically, one_by_one = node.set_parameters_atomically, node.set_parameters

    def checked(call, parameter_list):
        try:
            return call(parameter_list)
        except Exception as exc:    # an undeclared name: rclpy tells the caller
            _refused(node, health, parameter_list, exc)
            raise

    def set_parameters_atomically(parameter_list):
        result = checked(atomically, parameter_list)
        if not result.successful:
            _refused(node, health, parameter_list, result.reason)
        return result

    def set_parameters(parameter_list):
        results = checked(one_by_one, parameter_list)
        for p, result in zip(parameter_list, results):
            if not result.successful:
                _refused(node, health, [p], result.reason)
        return results

    node._fiber_align_refusals = health
    node.set_parameters_atomically = set_parameters_atomically
    node.set_parameters = set_parameters


def _refused(node, health, parameters, reason):
    names = ', '.join(p.name for p in parameters)
    text = 'parameter change refused: %s: %s' % (names, reason)
    node.get_logger().warning(text)
    health.warn(text)


class Health(Status):
    """
    Publish the node's health on ``/diagnostics``: the stand-in for ``diagnostic_updater``.

    The updater's shape (module docstring); the status, its latch and conditions are a
    :class:`~fiber_align.control.health.Status`. Each report is one DiagnosticArray:
    :meth:`~fiber_align.control.health.Status.reports`, the node's own status named after
    its fully qualified name. Every :attr:`ENDPOINT_EVERY` reports it looks for publishers
    of another type on the node's subscribed topics (their messages never arrive): a
    standing WARN naming them.
    """

    #: the condition key of the publishers of a wrong type
    FOREIGN = 'foreign_publishers'
    #: the endpoints are checked on every this many reports (the first included)
    ENDPOINT_EVERY = 4

    def __init__(self, node, period_s=0.5, hold_s=2.0, hardware_id='fiber_align', slack=None,
                 update=None, name=None, sender=None):
        """
        Create the publisher and a wall-clock timer (period in s).

        :param slack: a :class:`~fiber_align.control.cycle.Slack`: the periodic report
            then runs right after a cycle of the node's process, never just before one.
        :param update: called before each publish (a node's fresh status and values).
        :param name: the status name; ``None``: the node's fully qualified name (a node
            that reports several parts gives each its own, ``<node>/<part>``).
        :param sender: the process's :class:`~fiber_align.nodes.ros.sender.Sender`: the
            reports then leave the control thread (and carry its ``sender.*`` counts).
        """
        from rclpy.clock import Clock, ClockType
        super().__init__(hold_s)
        self._node = node
        self._name = name
        self._pub = node.create_publisher(DiagnosticArray, '/diagnostics', DIAG_QOS)
        self._sender = sender
        self._out = sender.writer(self._pub, False) if sender is not None else self._pub
        self._hw = hardware_id
        self._update = update
        self.sent = 0
        #: a :class:`~fiber_align.control.cycle.CycleStats` whose window is reported with
        #: every publish (per-sample nodes set it), or ``None``
        self.cycle = None
        self._slack = slack
        self._reports = 0
        self._check = None      # a check under way: (expected types, topics left, found)
        self._timer = node.create_timer(float(period_s), self._report,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))
        report_refusals(node, self)
        if sender is not None:
            # the listing of the check, off the control thread
            sender.watch_graph(node, float(period_s) * self.ENDPOINT_EVERY)

    def force_update(self):
        """Publish the node's status and run every task now, as the updater's call."""
        self.publish()

    def check_endpoints(self):
        """
        Set or clear the WARN of publishers of a wrong type on the node's topics, at once.

        :returns: the lines of :func:`~fiber_align.graph.endpoints.foreign_publishers`.
        """
        try:
            expected, todo = self._suspects()
            pubs = {t: self._publishers(t) for t in todo}
        except Exception:  # noqa: BLE001 - the context is shutting down
            return []
        return self._judge(expected, pubs)

    def _suspects(self):
        """
        Return the node's ``{topic: type}`` and the topics carrying another type.

        While the process's sender thread runs, the graph's listing is the one it made
        for the whole process (none yet: nothing to look up this time); else this node
        lists the graph itself.
        """
        node = self._node
        expected = {s.topic_name: type_name(s.msg_type) for s in node.subscriptions}
        sender = self._sender
        if sender is not None and sender.running:
            listing = sender.graph_topics() or ()
        else:
            listing = node.get_topic_names_and_types()
        return expected, suspect_topics(expected, listing)

    def _publishers(self, topic):
        return [(endpoint_node_name(i), i.topic_type)
                for i in self._node.get_publishers_info_by_topic(topic)]

    def _judge(self, expected, pubs):
        lines = foreign_publishers(expected, pubs)
        text = ('publisher of a wrong type: ' + '; '.join(lines)) if lines else None
        if text != self._conditions.get(self.FOREIGN):
            if text is None:
                self._conditions.pop(self.FOREIGN, None)
                self._node.get_logger().info('no publisher of a wrong type on my topics now')
            else:
                self._conditions[self.FOREIGN] = text
                self._node.get_logger().warning(text)
        return lines

    def _check_step(self):
        """
        One step of the endpoint check: a job of the process's slack.

        The first step lists the graph's topics (:func:`suspect_topics`); each next one
        looks up the publishers of one topic that carries another type (a few tenths of
        a millisecond on ``/diagnostics``); the last judges as :meth:`check_endpoints`.
        A step submits the next itself, so no job holds a control period long.
        """
        try:
            if self._check is None:
                expected, todo = self._suspects()
                self._check = (expected, todo, {})
            else:
                expected, todo, pubs = self._check
                topic = todo.pop()
                pubs[topic] = self._publishers(topic)
        except Exception:  # noqa: BLE001 - the context is shutting down
            self._check = None
            return
        expected, todo, pubs = self._check
        if todo:
            self._slack.submit(self._check_step)
            return
        self._check = None
        self._judge(expected, pubs)

    def _report(self):
        """
        Report periodically: publish the status; every few reports check the endpoints.

        The check (one listing of the graph's topics, then a query per topic that
        carries another type) is for a standing condition, so it runs every
        :attr:`ENDPOINT_EVERY` reports, one query per job of the process's slack
        (:meth:`_check_step`).
        """
        check = self._reports % self.ENDPOINT_EVERY == 0
        self._reports += 1
        if self._slack is None:
            if check:
                self.check_endpoints()
            self.publish()
            return
        if check and self._check is None:
            self._slack.submit(self._check_step)
        self._slack.submit(self.publish)

    def publish(self):
        """Publish the current status once (with the node's fresh ``sent.<topic>`` counts)."""
        if self._update is not None:
            self._update()
        counts = getattr(self._node, 'sent_counts', None)
        if counts is not None:
            self.values.update({'sent.' + k.lstrip('/'): v for k, v in counts().items()})
        if self.cycle is not None:
            self.values.update(self.cycle.window(time.monotonic_ns()))
        if self._sender is not None and self._sender.running:
            self.values.update(self._sender.stats())
        statuses = [self._message_of(*r) for r in self.reports(
            self._name or self._node.get_fully_qualified_name())]
        arr = DiagnosticArray(status=statuses)
        arr.header.stamp = self._node.get_clock().now().to_msg()
        try:
            self._out.publish(arr)
            self.sent += 1
        except Exception:  # noqa: BLE001 - context already shut down at exit
            pass

    def _message_of(self, name, level, message, values):
        st = DiagnosticStatus(level=bytes([level]), name=name, message=message,
                              hardware_id=self._hw)
        st.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]
        return st


def endpoint_node_name(info):
    """Return the fully qualified node name of a TopicEndpointInfo."""
    return node_fqn(info.node_name, info.node_namespace)


def _fmt(v):
    return repr(v) if isinstance(v, float) else str(v)
