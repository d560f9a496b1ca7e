# SPDX-License-Identifier: Apache-2.0
"""
A node's health on ``/diagnostics`` (diagnostic_msgs), with the status levels.

:class:`Health` is the stand-in for ``diagnostic_updater.Updater`` (not in a pip install
of ROS 2), with its shape: ``add(name, fn)`` tasks, each ``fn(stat)`` filling a
:class:`StatusWrapper` (``summary(level, message)``, ``add(key, value)``), the node's own
``summary(level, message)`` and ``force_update()``; swap it for the updater when installed.
"""

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from fiber_align.graph.endpoints import foreign_publishers, suspect_topics, type_name
from fiber_align.nodes.ros.qos import DIAG_QOS

#: DiagnosticStatus levels as ints (the message field is a byte).
OK, WARN, ERROR, STALE = 0, 1, 2, 3
#: The levels by the names a core's reports use.
LEVELS = {'ok': OK, 'warn': WARN, 'fail': ERROR}


def report_refusals(node, health):
    """
    Log every parameter change ``node`` refuses and report it on ``health`` (a WARN).

    Every path of a change ends in ``Node.set_parameters_atomically`` (the
    SetParameters and SetParametersAtomically services: ``ros2 param set``, a client) or
    ``Node.set_parameters`` (in-process): a descriptor's range, a read-only name, an
    undeclared one and the node's own check alike. The refusal goes to the caller with
    its reason and, here, to the node's log and ``/diagnostics``. Once per node (a node
    with several healths reports on its first).
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


class StatusWrapper:
    """
    The status a diagnostic task fills: the stand-in for ``DiagnosticStatusWrapper``.

    ``summary(level, message)`` sets the level (``OK``, ``WARN``, ``ERROR``: int) and
    text, ``add(key, value)`` a key/value pair (the unit in the key's name);
    ``merge_summary`` keeps the more severe of two summaries, joining the texts of equal
    ones, as the real wrapper's ``mergeSummary`` does.
    """

    def __init__(self, name=''):
        """Start OK with no message and no values; ``name``: the status's name."""
        self.name = name
        self.level = OK
        self.message = ''
        self.values = {}

    def summary(self, level, message):
        """Set the level (int) and the message (str)."""
        self.level, self.message = int(level), str(message)

    def merge_summary(self, level, message):
        """Raise the level to ``level`` with its message; an equal one adds its text."""
        level = int(level)
        if level > self.level:
            self.level, self.message = level, str(message)
        elif level == self.level and message:
            self.message = '; '.join(m for m in (self.message, str(message)) if m)

    def add(self, key, value):
        """Add the key/value pair ``key`` (str, its unit in the name) = ``value``."""
        self.values[str(key)] = value


class Health:
    """
    Publish the node's health on ``/diagnostics``: the stand-in for ``diagnostic_updater``.

    The updater's shape (module docstring). Each report is one DiagnosticArray: the node's
    own status, named after its fully qualified name, then one per task, named ``<node>:
    <task>``. ``warn``/``error`` latch their level for ``hold_s`` s (wall) so a short event
    is seen by every subscriber; ``condition`` sets a standing WARN until cleared;
    ``set_values`` adds key/value pairs (units in the key names). Every
    :attr:`ENDPOINT_EVERY` reports it looks for publishers of another type on the node's
    subscribed topics (their messages never arrive): a standing WARN naming them.
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
        self._node = node
        self._name = name
        self._pub = node.create_publisher(DiagnosticArray, '/diagnostics', DIAG_QOS)
        self._sender = sender
        self._out = sender.writer(self._pub, False) if sender is not None else self._pub
        self._hold_s = float(hold_s)
        self._hw = hardware_id
        self._level = OK
        self._message = 'ok'
        self._until = 0.0
        self._base_level = OK
        self._base_message = 'ok'
        self.values = {}
        self._conditions = {}
        self._update = update
        self._tasks = []
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

    def summary(self, level, message):
        """
        Set the node's steady level (``OK``, ``WARN``, ``ERROR``: int) and message.

        A status at least as severe as a latched event replaces it: the newer news wins
        (a device lost right after a refused configure reported the refusal for 2 s).
        """
        self._base_level, self._base_message = level, message
        if level >= self._level:
            self._until = 0.0

    def add(self, name, fn=None):
        """
        Add a diagnostic task, as ``diagnostic_updater.Updater.add``.

        :param name: the task's name (its status is ``<node>: <name>``), or a task
            object with ``name`` and ``run(stat)`` (a ``DiagnosticTask``).
        :param fn: ``fn(stat)`` fills a :class:`StatusWrapper` on every report; an
            exception it raises is reported as that task's ERROR.
        """
        if fn is None:
            name, fn = name.name, name.run
        self._tasks.append((str(name), fn))

    def force_update(self):
        """Publish the node's status and run every task now, as the updater's call."""
        self.publish()

    def resolve(self):
        """
        End a latched event now: the state it reported no longer holds.

        A configure that succeeds resolves the refusal before it; the steady status is
        then what the next publish reports.
        """
        self._until = 0.0

    @property
    def message(self):
        """Steady status text (str) of the node."""
        return self._base_message

    def _latch(self, level, message):
        self._level, self._message = level, message
        self._until = time.monotonic() + self._hold_s
        self.publish()

    def warn(self, message):
        """Report a WARN now and keep it for ``hold_s`` s."""
        self._latch(WARN, message)

    def error(self, message):
        """Report an ERROR now and keep it for ``hold_s`` s."""
        self._latch(ERROR, message)

    def condition(self, key, message=None, publish=True):
        """
        Set (``message``) or clear (``None``) the standing WARN ``key``; publish at once.

        While any is set the status is at least WARN and its message ends with theirs.
        ``publish`` False: the next report carries it (a caller inside that report).
        """
        if message is None:
            if self._conditions.pop(key, None) is None:
                return
        elif self._conditions.get(key) == message:
            return
        else:
            self._conditions[key] = message
        if publish:
            self.publish()

    def set_values(self, **values):
        """Set key/value pairs reported with the status."""
        self.values.update(values)

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
        if time.monotonic() < self._until and self._level >= self._base_level:
            level, message = self._level, self._message
        else:
            level, message = self._base_level, self._base_message
        if self._conditions:
            level = max(level, WARN)
            message = '; '.join([message] + list(self._conditions.values()))
        name = self._name or self._node.get_fully_qualified_name()
        statuses = [self._message_of(name, level, message, self.values)]
        for task, fn in self._tasks:
            stat = StatusWrapper('%s: %s' % (name, task))
            try:
                fn(stat)
            except Exception as exc:  # noqa: BLE001 - a task's failure is its status
                stat.summary(ERROR, 'task failed: %s: %s' % (type(exc).__name__, exc))
            statuses.append(self._message_of(stat.name, stat.level, stat.message,
                                             stat.values))
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
    ns = info.node_namespace.rstrip('/')
    return '%s/%s' % (ns, info.node_name)


def _fmt(v):
    return repr(v) if isinstance(v, float) else str(v)
