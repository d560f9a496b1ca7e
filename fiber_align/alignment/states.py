# SPDX-License-Identifier: Apache-2.0
"""The alignment sequencer's states (the ``alignment_state`` topic carries these names)."""

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
