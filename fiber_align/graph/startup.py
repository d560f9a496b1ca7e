# SPDX-License-Identifier: Apache-2.0
"""
A child that exits while the graph starts ends the whole launch, with its reason (pure).

Until ``lifecycle_manager`` logs that its start-up is done (:data:`STARTUP_DONE`), every
process is needed: one that exits then (a node refused a value, a device is missing)
leaves the others waiting for it for ever (the manager asked for
``actuator_driver/get_state`` every 5 s until Ctrl-C). :class:`StartupWatch` keeps each
process's last output line and answers, for an exit, the one line that ends the launch
(``launch/fiber_align.launch.py`` raises it: ``ros2 launch`` then stops every process and
exits 1). After start-up an exit leaves the rest running, as before (the driver's
watchdog holds the actuator). ``bringup`` watches its children itself
(:meth:`fiber_align.bringup.harness.Harness.alive`).
"""

#: What ``lifecycle_manager`` logs when its start-up sequence is done.
STARTUP_DONE = 'startup done'


class StartupWatch:
    """The start-up state of a launch and each process's last line of output."""

    def __init__(self):
        """Start-up not done; no output yet."""
        self.done = False
        self.last = {}                  # process name -> its last non-empty line

    def output(self, name, text):
        """Take output ``text`` (str or bytes) of process ``name``."""
        if isinstance(text, (bytes, bytearray)):
            text = text.decode('utf-8', 'replace')
        lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
        if lines:
            self.last[name] = lines[-1]
        if STARTUP_DONE in text:
            self.done = True

    def exit_reason(self, name, code, ends_graph=False, shutting_down=False):
        """
        Return the line that ends the launch for an exit of ``name``, or ``None``.

        :param code: its exit code.
        :param ends_graph: the process ends the graph anyway (the scenario runner's).
        :param shutting_down: the launch is stopping already (Ctrl-C, a shutdown).
        """
        if self.done or ends_graph or shutting_down:
            return None
        why = self.last.get(name, '')
        return '%s exited with code %s during start-up%s' % (
            name, code, (': ' + why) if why else '')
