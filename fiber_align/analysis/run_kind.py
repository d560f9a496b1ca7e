# SPDX-License-Identifier: Apache-2.0
"""
What kind of run a bag holds, and the alignment figures of an alignment run.

A bag is an **alignment** run when its ``alignment_state`` stream (std_msgs/String, the
sequencer's JSON status or a bare state name) shows the sequencer out of IDLE: the
setpoint then is the sequencer's search, whose jumps are no setpoint steps to score. A
bag with a setpoint otherwise is a **tracking** run (step, sine, triangle ...); one with
drive and displacement but no setpoint an **open-loop** run (hysteresis experiment).

The alignment figures are those ``bringup`` prints for an ``align`` run
(:func:`fiber_align.analysis.run_summary.align_figures`), with the events read from the
state stream and the losses measured, since a bag knows no optics model: against the
bag's peak power, the highest mean of the power over :data:`REFERENCE_WINDOW_S` (a mean,
so that detector noise does not lift the reference).
"""

import json

import numpy as np

from fiber_align.alignment import states as st
from fiber_align.analysis.run_summary import align_figures, LEVEL_S

ALIGNMENT = 'alignment'
TRACKING = 'tracking'
OPEN_LOOP = 'open-loop'
#: s: the window of the running mean whose highest value is the reference power
REFERENCE_WINDOW_S = LEVEL_S
#: states that show the sequencer aligning (anything but IDLE)
_ALIGNING = tuple(s for s in st.STATES if s != st.IDLE)


def parse_states(msgs):
    """
    Return the status dicts of ``alignment_state`` messages, in order.

    A message that is no JSON object is read as a bare state name (``{'state': text}``).
    """
    out = []
    for m in msgs:
        text = getattr(m, 'data', m)
        try:
            d = json.loads(text)
        except (TypeError, ValueError):
            d = None
        out.append(d if isinstance(d, dict) else {'state': str(text)})
    return out


def run_kind(statuses, has_setpoint):
    """Return the kind of run (:data:`ALIGNMENT`, :data:`TRACKING`, :data:`OPEN_LOOP`)."""
    if any(s.get('state') in _ALIGNING for s in statuses):
        return ALIGNMENT
    return TRACKING if has_setpoint else OPEN_LOOP


def state_indices(statuses, recv_ns, base_recv_ns, base_stamp_ns=None):
    """
    Return the sample index from which each status holds.

    With the samples' stamps and a status ``sample_time_s`` (the stamp of the sample the
    sequencer stepped last, s): the sample after that one. Otherwise by receive time: the
    first sample received after the status.

    :param recv_ns: receive times of the statuses (ns); :param base_recv_ns: receive
        times of the samples (ns, sorted); :param base_stamp_ns: their stamps (ns) or None.
    """
    out = np.searchsorted(base_recv_ns, np.asarray(recv_ns, np.int64), side='right')
    if base_stamp_ns is not None:
        for i, s in enumerate(statuses):
            ts = s.get('sample_time_s')
            if isinstance(ts, (int, float)) and np.isfinite(ts):
                out[i] = np.searchsorted(base_stamp_ns, int(round(ts * 1e9)), side='right')
    return [int(k) for k in np.minimum(out, len(base_recv_ns))]


def events_from_states(states, n):
    """
    Return the run's events (sample indices) from ``[(index, status)]`` of ``n`` samples.

    ``align``: the first state out of IDLE; ``tracking``: the first TRACKING from there;
    ``cycles``: ``(off, on, end)`` for every return from RELEASING / IDLE to an active
    state after TRACKING (the switch off and on), ``end`` the next switch off or ``n``.
    """
    ev = {}
    ka = next((k for k, s in states if s.get('state') in _ALIGNING), None)
    if ka is None:
        return ev
    ev['align'] = ka
    kt = next((k for k, s in states if k >= ka and s.get('state') == st.TRACKING), None)
    if kt is None:
        return ev
    ev['tracking'] = kt
    offs, ons, prev = [], [], st.TRACKING
    for k, s in states:
        name = s.get('state')
        if k <= kt or name == prev:
            continue
        if prev in st.ACTIVE and name in (st.RELEASING, st.IDLE):
            offs.append(k)
        elif prev in (st.RELEASING, st.IDLE) and name in st.ACTIVE and offs:
            ons.append((offs[-1], k))
        prev = name
    cycles = []
    for k_off, k_on in ons:
        k_end = next((k for k in offs if k > k_on), n)
        if k_end > k_on > k_off:
            cycles.append((k_off, k_on, k_end))
    ev['cycles'] = cycles
    return ev


def reference_power(p, n):
    """Return the highest mean (W) of ``n`` consecutive readings of ``p`` (NaN: skipped)."""
    ok = np.isfinite(p)
    x = np.where(ok, p, 0.0)
    n = max(1, min(int(n), x.size))
    c = np.concatenate([[0.0], np.cumsum(x)])
    k = np.concatenate([[0], np.cumsum(ok)])
    cnt = k[n:] - k[:-n]
    with np.errstate(invalid='ignore', divide='ignore'):
        mean = np.where(cnt > 0, (c[n:] - c[:-n]) / np.maximum(cnt, 1), -np.inf)
    return float(np.max(mean))


def alignment_metrics(t, p, states, threshold_w):
    """
    Return the alignment figures of a bag (SI; losses in dB against its peak power).

    :param t: sample times (s); :param p: optical power per sample (W, NaN where none).
    :param states: ``[(sample index, status)]`` from :func:`state_indices`.
    :param threshold_w: light threshold (W) when the statuses name none.
    """
    t = np.asarray(t, float)
    p = np.asarray(p, float)
    ok = np.isfinite(p) & (p > 0)
    if t.size < 2 or not ok.any():
        return {'samples': int(t.size)}
    rate_hz = 1.0 / float(np.median(np.diff(t)))
    ref = reference_power(np.where(ok, p, np.nan), round(REFERENCE_WINDOW_S * rate_hz))
    with np.errstate(divide='ignore', invalid='ignore'):
        loss = np.where(ok, 10.0 * np.log10(ref / np.where(ok, p, 1.0)), np.inf)
    if not any(s.get('threshold_w') for _, s in states):
        states = [(k, dict(s, threshold_w=threshold_w)) for k, s in states]
    out = align_figures(t, p, loss, states, events_from_states(states, t.size), rate_hz)
    out['reference_power_w'] = ref
    out['reference_window_s'] = REFERENCE_WINDOW_S
    out['switch_cycles'] = len(out.get('cycles', []))
    return out
