# SPDX-License-Identifier: Apache-2.0
"""
Has the recorder caught up? One rule for ``bringup`` and ``scenario_runner``.

Every node reports ``sent.<topic>`` (messages published) and ``bag_recorder`` reports
``recorded.<topic>`` for every topic it is asked to record (0 until it has subscribed)
on ``/diagnostics``. The recorder holds what the nodes sent once, in reports made after
the graph stopped publishing, every recorded count is at least the matching sent count.
Pure: the callers keep the newest report of each node, ``{node: {key: value, '_t':
monotonic s of arrival}}``. A recorder whose disk filled up (``stopped_early`` on its
report) holds all it ever will: nothing is left to wait for.
"""

RECORDER = 'bag_recorder'
#: The recorder's value, once a write failed (a full disk): the one line saying so.
STOPPED_EARLY = 'stopped_early'
#: Its setpoints are recorded as the compensator's ``reference``, not by name.
NOT_RECORDED = ('scenario_runner',)


def diag_entry(status, now):
    """
    Return ``(node, values)`` of one ``diagnostic_msgs/DiagnosticStatus`` as kept here.

    :param status: the status (``name``, ``level`` as bytes or int, ``message``,
        ``values``).
    :param now: its arrival (monotonic s), kept as ``_t``.
    :returns: the node's base name and ``{key: value, 'level': int, 'message': str,
        '_t': now}``.
    """
    lvl = status.level
    lvl = lvl[0] if isinstance(lvl, (bytes, bytearray)) else int(lvl)
    vals = {kv.key: kv.value for kv in status.values}
    return status.name.rsplit('/', 1)[-1], {'level': lvl, 'message': status.message,
                                            '_t': now, **vals}


def recorder_short(diag, since, names=None):
    """
    Return ``None`` until the reports are fresh, then ``{topic: (recorded, sent)}`` left.

    :param diag: node -> its newest ``/diagnostics`` values (with ``_t``, monotonic s).
    :param since: monotonic s; only reports that arrived after it count.
    :param names: the nodes whose ``sent.*`` counts must be recorded; ``None``: every
        node that reports one.
    :returns: ``None`` while the recorder or a node has not reported since ``since``;
        else the topics the recorder is short of (empty: caught up).
    """
    rec = diag.get(RECORDER, {})
    if rec.get('_t', 0.0) <= since:
        return None
    if rec.get(STOPPED_EARLY):
        return {}                       # a full disk: the bag holds all it ever will
    got = {k.rsplit('/', 1)[-1]: int(v) for k, v in rec.items() if k.startswith('recorded.')}
    if names is None:
        names = [n for n, d in diag.items()
                 if n != RECORDER and any(k.startswith('sent.') for k in d)]
    short = {}
    for node in names:
        if node in NOT_RECORDED:
            continue
        d = diag.get(node, {})
        if d.get('_t', 0.0) <= since:
            return None
        for k, v in d.items():
            topic = k[len('sent.'):].rsplit('/', 1)[-1] if k.startswith('sent.') else None
            if topic in got and got[topic] < int(float(v)):
                short[topic] = (got[topic], int(float(v)))
    return short


def recorder_stopped(diag):
    """
    Return the recorder's line when its recording stopped early (a full disk), or None.

    :param diag: node (or full status name) -> its newest ``/diagnostics`` values.
    """
    return next((v.get(STOPPED_EARLY) for k, v in diag.items()
                 if k.rsplit('/', 1)[-1] == RECORDER and v.get(STOPPED_EARLY)), None)


def recorder_missing(diag, since, names=None):
    """
    Return ``None`` until the reports are fresh, then the topics sent but not recorded.

    For a graph that keeps publishing (realtime), where the counts of two reports never
    agree: every topic a node has sent on must be in the bag, the rest of its messages
    reach the recorder before it closes (it drains its readers). Arguments as
    :func:`recorder_short`.
    """
    short = recorder_short(diag, since, names)
    return None if short is None else sorted(t for t, (rec, _) in short.items() if rec == 0)


def left_text(left):
    """
    Return what the recorder does not hold, for a person.

    :param left: what :func:`recorder_short` (``{topic: (recorded, sent)}``) or
        :func:`recorder_missing` (topics) returned; ``None``: no fresh reports.
    """
    if left is None:
        return 'no fresh /diagnostics reports'
    if isinstance(left, dict):
        return ', '.join('%s %d of %d' % (k, r, n) for k, (r, n) in sorted(left.items()))
    return 'nothing of ' + ', '.join(left)


def recorder_short_full(diag, since, nodes, base=None):
    """
    :func:`recorder_short` for reports keyed by full status names (the multi-axis graphs).

    The rig's and the station's axes publish the same relative topics in their own
    namespaces, so the counts are matched by full topic name: a node's ``sent.<topic>``
    is ``<its namespace>/<topic>`` (or ``/<topic>``, an absolute one such as ``/clock``)
    and the recorder's ``recorded.<full topic>``.

    :param diag: full status name (``/station/in/x/simulated_actuator``) -> its newest
        values (with ``_t``, monotonic s).
    :param nodes: the full names of the nodes whose ``sent.*`` counts must be recorded.
    :param base: ``{topic: (recorded, sent)}`` when the recorder had matched every writer
        (:func:`recorder_counts`): only what was sent after it counts (a volatile
        message published before the match cannot reach any late reader).
    :returns: ``None`` while a report is older than ``since``; else ``{topic: (recorded,
        sent)}`` (since ``base``) of the topics the recorder is short of.
    """
    now = recorder_counts(diag, nodes, since)
    if now is None:
        return None
    short = {}
    for t, (got, sent) in now.items():
        r0, s0 = (base or {}).get(t, (0, 0))
        if got - r0 < sent - s0:
            short[t] = (got - r0, sent - s0)
    return short


def recorder_counts(diag, nodes, since=-1.0):
    """
    Return ``{full topic: (recorded, sent)}`` of the recorded topics, or ``None``.

    ``None`` while the recorder's or a node's newest report is older than ``since``
    (monotonic s). Arguments as :func:`recorder_short_full`.
    """
    rec = next((v for k, v in diag.items() if k.rsplit('/', 1)[-1] == RECORDER), {})
    if rec.get('_t', 0.0) <= since:
        return None
    if rec.get(STOPPED_EARLY):
        return {}                       # a full disk: the bag holds all it ever will
    got = {k[len('recorded.'):]: int(float(v)) for k, v in rec.items()
           if k.startswith('recorded.')}
    sent = {}
    for node in nodes:
        if node.rsplit('/', 1)[-1] in NOT_RECORDED + (RECORDER,):
            continue
        d = diag.get(node, {})
        if d.get('_t', 0.0) <= since:
            return None
        ns = node.rpartition('/')[0]
        for k, v in d.items():
            if not k.startswith('sent.'):
                continue
            t = k[len('sent.'):]
            full = next((f for f in (ns + '/' + t, '/' + t) if f in got), None)
            if full is not None:
                sent[full] = sent.get(full, 0) + int(float(v))
    return {t: (got[t], n) for t, n in sent.items()}
