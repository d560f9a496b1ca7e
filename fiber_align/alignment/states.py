# SPDX-License-Identifier: Apache-2.0
"""The alignment sequencer's states (the ``alignment_state`` topic carries these names)."""

IDLE = 'IDLE'
SEARCHING = 'SEARCHING'
PEAKING = 'PEAKING'
TRACKING = 'TRACKING'
RELEASING = 'RELEASING'
FAULT = 'FAULT'
STATES = (IDLE, SEARCHING, PEAKING, TRACKING, RELEASING, FAULT)
ACTIVE = (SEARCHING, PEAKING, TRACKING)
