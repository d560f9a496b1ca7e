# SPDX-License-Identifier: Apache-2.0
"""
The drive a sample-clocked DAC latched at clock edges its simulation slept through.

A DAC clocked at the sample rate latches, at each clock edge, the last value written to
it before that edge, and the amplifier holds it for one period. A simulated plant whose
process stalled for ``n`` periods must advance over those periods afterwards; the values
written meanwhile (``writes``, in order) arrive only when it wakes, without their times.
Holding the newest of them for the whole stall, or the value before it, turns every ramp
the driver made meanwhile (its watchdog's ramp to the safe voltage, 2 V a period) into
one step, which rings the bending mode by the step's full height (a 52 V step: -20 um).
:func:`replay_edges` spreads the writes evenly over the stall instead: no write is
skipped while there are no more writes than edges, so the plant sees the driver's ramp
as a ramp (slower than it was, never steeper) and ends at the newest value.
"""


def replay_edges(prev, writes, n):
    """
    Return the values (V) latched at the ``n`` edges of a stall, the last edge's last.

    The ``m`` writes are taken as evenly spaced over the ``n`` periods, the last one at
    the last edge: edge ``j`` (1..n) latches the ``floor(j m / n)``-th write, or ``prev``
    before the first. With ``m <= n`` consecutive edges latch consecutive writes or the
    same one, so none is skipped; with ``m > n`` some are (at most ``ceil(m / n) - 1``
    between two edges), as a DAC that is written faster than it is clocked skips them.

    :param prev: the value (V) latched at the edge before the stall.
    :param writes: the values (V) written since, oldest first.
    :param n: edges (periods) to fill, >= 1.
    :returns: a list of ``n`` values (V); the last is ``writes[-1]`` (``prev`` if none).
    """
    n = int(n)
    if n < 1:
        raise ValueError('n must be >= 1, got %d' % n)
    m = len(writes)
    out = []
    for j in range(1, n + 1):
        i = j * m // n
        out.append(writes[i - 1] if i else prev)
    return out
