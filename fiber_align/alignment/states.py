# SPDX-License-Identifier: Apache-2.0
"""
What the ``alignment_state`` topic carries: the sequencer's states, and its texts' units.

The states' names; :func:`um` and :func:`dbm`, the one way every machine writes a position
(m) and a power (W) in its events and fault reasons.
"""

import math

import numpy as np

IDLE = 'IDLE'
SEARCHING = 'SEARCHING'
PEAKING = 'PEAKING'
TRACKING = 'TRACKING'
RELEASING = 'RELEASING'
FAULT = 'FAULT'
#: The driver holds its output (a trip, disabled, inactive): the setpoint is held until
#: the re-arm, then the sequencer re-peaks (``fiber_align.alignment.hold``).
HELD = 'HELD'
STATES = (IDLE, SEARCHING, PEAKING, TRACKING, RELEASING, FAULT, HELD)
ACTIVE = (SEARCHING, PEAKING, TRACKING)


def um(v):
    """Return a position (m; one value or several) as text in um."""
    v = np.atleast_1d(np.asarray(v, dtype=float))
    if v.size == 1:
        return '%.2f um' % (v[0] * 1e6)
    return '(%s) um' % ', '.join('%.2f' % (q * 1e6) for q in v)


def dbm(p_w):
    """Return ``p_w`` (W) in dBm for messages; ``nan`` for ``None``."""
    if p_w is None:
        return float('nan')
    return 10.0 * math.log10(max(p_w, 1e-15) / 1e-3)
