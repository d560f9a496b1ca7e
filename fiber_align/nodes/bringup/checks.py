# SPDX-License-Identifier: Apache-2.0
"""``bringup``'s checks of a graph: endpoints, environment, recorder catch-up, usage."""

import time

from fiber_align.nodes._recording import recorder_short
from fiber_align.nodes.graph import dds_environment  # noqa: F401 - bringup's API
from fiber_align.nodes.bringup.children import cpu_time_s, rss_bytes


def expected_endpoints(scenario, lockstep, recorded=(), composed=False):
    """
    Return ``{topic: (publishers, subscribers)}`` (at least) the running graph must have.

    :param scenario: a scenario name of ``bringup``.
    :param lockstep: the plant publishes ``/clock``.
    :param recorded: the topics a recorder subscribes to (its ``topics`` parameter;
        empty: no recorder).
    :param composed: the control nodes share one process: their readers of each other's
        topics are in-process (``_common.LocalBus``), not DDS subscriptions.
    """
    inner = 0 if composed else 1
    if scenario == 'hysteresis-experiment':
        out = {'displacement': (1, 1 + inner), 'feedforward_voltage': (1, inner),
               'feedback_voltage': (1, inner), 'drive_voltage': (1, 1 + inner),
               'optical_power': (1, 0)}
    else:
        source = 0 if scenario == 'none' else 1
        out = {'displacement': (1, 1 + inner * (1 + source)),
               'setpoint': (source, 1 if scenario == 'none' else inner),
               'reference': (1, inner), 'feedforward_voltage': (1, inner),
               'feedback_voltage': (1, inner), 'controller_state': (1, 0),
               'drive_voltage': (1, 1 + inner), 'optical_power': (1, 0)}
    if scenario == 'align':
        out.update({'reference': (1, 1 + inner), 'optical_power': (1, 1 + inner),
                    'alignment_state': (1, 1)})
    if lockstep:
        out['/clock'] = (1, 0)
    recorded = {t.lstrip('/') for t in recorded}
    return {k: (p, s + (1 if p and k.lstrip('/') in recorded else 0))
            for k, (p, s) in out.items()}


def wait_recorder(diag, names, ch, limit_s):
    """
    Wait until the recorder holds every message the nodes sent; return (s waited, short).

    The rule is :func:`fiber_align.nodes._recording.recorder_short`; only reports made
    after the plant was held count. Reliable delivery may need a retransmission after a
    burst, so the wait is on the counts themselves, bounded by ``limit_s`` (s).
    ``short``: topic -> (recorded, sent) left.
    """
    t0 = time.monotonic()
    short = None
    while time.monotonic() - t0 < limit_s and ch.alive():
        time.sleep(0.05)
        now = recorder_short(diag, t0, names)
        if now is not None:
            short = now
            if not short:
                break
    return time.monotonic() - t0, short or {}


def usage(children, cpu0):
    """Return CPU (s per s of run) and resident memory (MB) of every child process."""
    out = {}
    for ch in children:
        t_a, c_a = cpu0.get(ch.name, (None, 0.0))
        c_b, wall = cpu_time_s(ch.proc.pid), time.monotonic() - (t_a or time.monotonic())
        out[ch.name] = {'cpu_per_s': (c_b - c_a) / wall if wall > 0 else None,
                        'rss_mb': rss_bytes(ch.proc.pid) / 1e6}
    return out
