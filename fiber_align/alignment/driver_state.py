# SPDX-License-Identifier: Apache-2.0
"""
What an alignment sequencer knows of its actuator drivers, from what the drivers publish.

A sequencer may only move the light while its drivers drive. It learns their state from
three things each driver publishes (the node turns each message into one call here):

- ``drive_held`` (latched Bool): :meth:`DriverState.held`; true while the driver holds
  its output (a watchdog trip, ``~/enable`` false, inactive, unconfigured, device lost);
- ``~/transition_event`` (lifecycle_msgs/TransitionEvent): :meth:`DriverState.lifecycle`
  with the label of the goal state (``unconfigured``, ``inactive``, ``active``,
  ``errorprocessing``, ...);
- ``/diagnostics``: :meth:`DriverState.diagnostics`, a status at ERROR or above; used only
  until the driver's ``drive_held`` is heard (a driver of an older build);

and :meth:`DriverState.gone` when the node sees that the driver's ``drive_held``
publisher vanished (its process ended).

The rules (:attr:`DriverState.active`, :attr:`DriverState.reason`):

1. a driver whose publisher vanished is down (lost) until it publishes again;
2. a driver whose last heard lifecycle state is not ``active`` is down, whatever its last
   ``drive_held`` said (a ``drive_held`` false from before the transition is stale);
3. a driver whose last ``drive_held`` is true is down;
4. otherwise it drives (``drive_held`` false, lifecycle ``active`` or never heard: the
   transition events are volatile, so a sequencer started after its driver hears none);
   with no ``drive_held`` heard its ``/diagnostics`` decides (ERROR: down), else unknown.

The two inputs come on two topics, so they are not ordered with respect to each other.
A driver's ``drive_held`` true is published before it leaves ``active`` and its false
while it activates (``on_activate``), so after a re-activation the false may still be in
flight when the event ``active`` arrives: the last ``drive_held`` true heard before that
event is *pending* (:attr:`DriverState.pending`). The driver still counts as down for the
loop (the sequencer holds its setpoint until the false arrives), but a command is not
refused for it (:meth:`DriverState.refusal`): the first ``align`` after a re-plug and
re-activation is accepted and goes on once the false arrives.
"""

ACTIVE = 'active'
#: What a lifecycle state means, for the reasons (labels of lifecycle_msgs/State).
STATE_TEXT = {
    'unconfigured': 'unconfigured (no device, no output)',
    'inactive': 'inactive (output at the safe voltage)',
    'finalized': 'finalized (shut down)',
    'configuring': 'configuring',
    'cleaningup': 'cleaning up',
    'shuttingdown': 'shutting down',
    'activating': 'activating',
    'deactivating': 'deactivating (ramping to the safe voltage)',
    'errorprocessing': 'in error processing (its device was lost or a transition failed)',
}


class _One:
    """What is known of one driver (see :class:`DriverState`)."""

    __slots__ = ('held', 'life', 'diag_ok', 'gone', 'held_n', 'active_n')

    def __init__(self):
        self.held = None        # last drive_held (None: unheard)
        self.life = None        # label of the last lifecycle goal state (None: unheard)
        self.diag_ok = None     # last /diagnostics level below ERROR (None: unheard)
        self.gone = False       # its drive_held publisher vanished
        self.held_n = -1        # input count when drive_held was last heard
        self.active_n = -1      # input count when the lifecycle last entered 'active'


class DriverState:
    """
    The state of the drivers of one sequencer, from their messages (module docstring).

    :param names: the drivers' names (the node's names for them, e.g. ``actuator_driver``
        or ``x/actuator_driver``); the first is the default of each call.
    """

    def __init__(self, names=('actuator_driver',)):
        """Start with nothing heard of any driver (:attr:`active` is ``None``)."""
        self.names = tuple(names)
        self._d = {n: _One() for n in self.names}
        self._n, self._memo = 0, {}     # each, pending: asked every period, changed by a call
        #: count of calls that changed :attr:`active` or :attr:`reason`
        self.changes = 0

    def _one(self, name):
        self._memo = {}                 # every change of a driver's state comes through here
        return self._d[self.names[0] if name is None else name]

    def _changed(self, before):
        if (self.active, self.reason) != before:
            self.changes += 1
            return True
        return False

    # -- inputs (each returns True when the state or its reason changed) -----------
    def held(self, held, name=None):
        """Take the driver's latched ``drive_held`` (bool)."""
        before, d = (self.active, self.reason), self._one(name)
        self._n += 1
        d.held, d.held_n, d.gone = bool(held), self._n, False
        return self._changed(before)

    def lifecycle(self, state, name=None):
        """Take the goal state label of the driver's ``~/transition_event`` (str)."""
        before, d = (self.active, self.reason), self._one(name)
        self._n += 1
        d.life, d.gone = str(state), False
        if d.life == ACTIVE:
            d.active_n = self._n
        return self._changed(before)

    def diagnostics(self, ok, name=None):
        """Take the driver's ``/diagnostics`` level: ``ok`` is False at ERROR or above."""
        before, d = (self.active, self.reason), self._one(name)
        d.diag_ok = bool(ok)
        return self._changed(before)

    def gone(self, name=None):
        """Note that the driver's ``drive_held`` publisher vanished (its process ended)."""
        before, d = (self.active, self.reason), self._one(name)
        d.gone = True
        return self._changed(before)

    # -- the state ------------------------------------------------------------------
    @staticmethod
    def _pending(d):
        return bool(d.held) and d.life == ACTIVE and d.held_n < d.active_n

    @staticmethod
    def _down(d):
        """Return why driver ``d`` does not drive ('' when it does, None: unknown)."""
        if d.gone:
            return 'lost (its process is gone: no drive_held publisher)'
        if d.life is not None and d.life != ACTIVE:
            return STATE_TEXT.get(d.life, d.life)
        if d.held:
            if DriverState._pending(d):
                return 'activated, drive_held true not yet cleared'
            return ('holding its output (drive_held true: a watchdog trip, ~/enable false '
                    'or inactive)')
        if d.held is None:
            if d.diag_ok is False:
                return 'reporting ERROR on /diagnostics'
            if d.diag_ok is None and d.life is None:
                return None
        return ''

    @property
    def active(self):
        """Return False when a driver is down, True when every one drives, else None."""
        why = [self._down(d) for d in self._d.values()]
        if any(w for w in why):
            return False
        return True if all(w == '' for w in why) else None

    @property
    def each(self):
        """Return per driver (in ``names`` order) False when down, True when driving, else None."""
        if 'each' not in self._memo:
            self._memo['each'] = tuple(False if w else (True if w == '' else None)
                                       for w in map(self._down, self._d.values()))
        return self._memo['each']

    @property
    def reason(self):
        """Return why the drivers are not all driving ('' when they are, or unknown)."""
        out = []
        for n, d in self._d.items():
            w = self._down(d)
            if w:
                out.append('%s %s' % (n, w))
        return '; '.join(out)

    @property
    def pending(self):
        """Return True when a driver is down only by a ``drive_held`` true from before."""
        if 'pending' not in self._memo:
            self._memo['pending'] = any(self._pending(d) for d in self._d.values()) and all(
                self._down(d) in ('', None) or self._pending(d) for d in self._d.values())
        return self._memo['pending']

    def refusal(self, what='align'):
        """
        Return ``None`` or why a command that moves the light (``what``) is refused now.

        Refused while a driver is down, but not for a ``drive_held`` true that a newer
        activation will clear (:attr:`pending`); the message says what to do.
        """
        if self.active is not False or self.pending:
            return None
        howto = []
        for d in self._d.values():
            w = self._down(d)
            if not w or self._pending(d):
                continue
            if d.gone:
                howto.append('start the driver')
            elif d.life is not None and d.life != ACTIVE:
                howto.append('configure and activate it (lifecycle_manager startup, or '
                             'ros2 lifecycle set <driver> configure, then activate)')
            else:
                howto.append('re-arm it (~/enable true, or a lifecycle deactivate and '
                             'activate)')
        return ('refused: the driver is not active: %s; %s, then %s'
                % (self.reason, '; '.join(dict.fromkeys(howto)), what))
