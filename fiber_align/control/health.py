# SPDX-License-Identifier: Apache-2.0
"""
A node's health, pure: the status levels, the latched events, the standing conditions.

What a node reports on ``/diagnostics`` (:class:`fiber_align.nodes.ros.diagnostics.Health`
publishes it): :class:`Status`, its steady summary, its events latched for ``hold_s`` s,
its standing conditions, its key/value pairs and its diagnostic tasks, each filling a
:class:`StatusWrapper` (the stand-in for ``diagnostic_updater.DiagnosticStatusWrapper``).
"""

import time

#: DiagnosticStatus levels as ints (the message field is a byte).
OK, WARN, ERROR, STALE = 0, 1, 2, 3
#: The levels by the names a core's reports use.
LEVELS = {'ok': OK, 'warn': WARN, 'fail': ERROR}


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


class Status:
    """
    A node's status, as ``diagnostic_updater.Updater`` keeps it.

    ``summary`` sets the steady level and message; ``warn``/``error`` latch their level
    for ``hold_s`` s (wall) so a short event is seen by every subscriber; ``condition``
    sets a standing WARN until cleared; ``set_values`` adds key/value pairs (units in the
    key names); ``add`` a diagnostic task. :meth:`reports` is what one report says;
    :meth:`publish` sends it (a node's ``Health``; here nothing).
    """

    def __init__(self, hold_s=2.0):
        """Start OK (``hold_s``: how long an event is latched, s)."""
        self._hold_s = float(hold_s)
        self._level = OK
        self._message = 'ok'
        self._until = 0.0
        self._base_level = OK
        self._base_message = 'ok'
        self.values = {}
        self._conditions = {}
        self._tasks = []

    def publish(self):
        """Send the status now: a node's ``Health`` publishes it; here nothing."""

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

    def reports(self, name):
        """
        Return the statuses of one report: ``[(name, level, message, values), ...]``.

        The node's own first, named ``name``: the latched event while it holds and is at
        least as severe as the steady status, else the steady status, raised to WARN by
        any standing condition; then one per task, named ``<name>: <task>``.
        """
        if time.monotonic() < self._until and self._level >= self._base_level:
            level, message = self._level, self._message
        else:
            level, message = self._base_level, self._base_message
        if self._conditions:
            level = max(level, WARN)
            message = '; '.join([message] + list(self._conditions.values()))
        out = [(name, level, message, self.values)]
        for task, fn in self._tasks:
            stat = StatusWrapper('%s: %s' % (name, task))
            try:
                fn(stat)
            except Exception as exc:  # noqa: BLE001 - a task's failure is its status
                stat.summary(ERROR, 'task failed: %s: %s' % (type(exc).__name__, exc))
            out.append((stat.name, stat.level, stat.message, stat.values))
        return out
