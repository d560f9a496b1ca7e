# SPDX-License-Identifier: Apache-2.0
"""
The QoS profiles of the fiber_align topics, each distinct policy written once.

Chosen so that nothing a publisher sent is lost silently and no control reader works
through a backlog (docs/ros_interface.md, "Topics"). Two names for one policy are the
same object.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Messages of history every per-sample publisher keeps (5 s at the default 1 kHz):
#: a reader that falls behind (the recorder on a loaded machine) catches up from the
#: writer's history instead of losing samples, and the writer never blocks on it.
SAMPLE_DEPTH = 5000


def profile(depth, reliable, latched):
    """Return a KEEP_LAST profile ``depth`` deep, reliable or best effort, latched or volatile."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                      else DurabilityPolicy.VOLATILE)


#: Lockstep per-sample publishers: reliable, :data:`SAMPLE_DEPTH` deep, transient local,
#: so a reader that matched the writer a moment after a sample was published
#: (multi-process lockstep start-up) still receives it.
CONTROL_QOS = profile(SAMPLE_DEPTH, True, True)
#: Realtime per-sample publishers: reliable and as deep (a matched reader that fell
#: behind catches up from the writer's history), but volatile: a reader that joins
#: (``ros2 topic echo``, a plot, the live view) sees the present, not seconds of replay,
#: and the writer does not send its whole history to it from the control thread. A
#: recorder that must hold every sample is waited for before the plant's clock starts
#: (``simulated_actuator`` ``start_after_readers``).
LIVE_QOS = profile(SAMPLE_DEPTH, True, False)
#: Lockstep readers of the per-sample topics: index pairing needs every message,
#: including one published before the match completed.
LOCKSTEP_QOS = CONTROL_QOS
#: ``/clock``: as deep and as durable as the control topics, so a lagging or late
#: recorder loses no tick (rclpy's TimeSource subscribes best effort: it matches).
CLOCK_QOS = CONTROL_QOS
#: ``/diagnostics`` and other low-rate reports: reliable, volatile, depth 10.
DIAG_QOS = profile(10, True, False)
#: A lifecycle node's ``~/transition_event`` (rcl's publisher: reliable, volatile, depth
#: 10): the sequencers read every transition of their drivers.
TRANSITION_EVENT_QOS = DIAG_QOS
#: Realtime control readers of the per-sample topics: only the newest message matters,
#: so a node that fell behind skips stale samples. Best effort, as ROS's sensor-data
#: profile (a reliable reader would hold every newer sample behind one lost on the way);
#: volatile. Matches the reliable publishers.
REALTIME_QOS = profile(1, False, False)
#: The realtime simulated plant's ``drive_voltage`` reader: the DAC it stands for sees
#: every value the driver wrote, so after a stall it can replay the ones written
#: meanwhile (:mod:`fiber_align.plant.dac`); as :data:`REALTIME_QOS`, but deep.
DAC_QOS = profile(SAMPLE_DEPTH, False, False)
#: State topics published on change only (``drive_held``, ``alignment_state``, the
#: realtime ``reference``): a late joiner (a restarted node) gets the present state.
LATCHED_QOS = profile(1, True, True)
REFERENCE_LATCHED_QOS = LATCHED_QOS
#: ``alignment_state``: latched, and deep: two changes one update apart (SEARCHING then
#: PEAKING) reached a depth-1 reader that lagged as one, and the lost SEARCHING put a
#: lockstep run's ``align`` one sample late (a loaded machine: 3 of 6 array runs). A reader
#: that wants only the present keeps depth 1 (the live view); one that wants every change
#: (bringup, the recorder) takes this depth too. 100 changes: far more than a run makes
#: between two reads.
STATE_QOS = profile(100, True, True)
#: The user's ``setpoint``: reliable, volatile, deep (every setpoint is checked, so each
#: bad one is reported); a default rclpy or ``ros2 topic pub`` publisher matches it.
SETPOINT_QOS = profile(SAMPLE_DEPTH, True, False)


def sample_pub_qos(lockstep):
    """
    Return the publisher QoS of a per-sample topic for the sync mode.

    :param lockstep: True in lockstep (:data:`CONTROL_QOS`: transient local, a late
        matched reader gets every sample), False in realtime (:data:`LIVE_QOS`).
    """
    return CONTROL_QOS if lockstep else LIVE_QOS


def sample_qos(lockstep):
    """
    Return the subscription QoS of a per-sample topic for the sync mode.

    :param lockstep: True in lockstep (deep queue: index pairing needs every message),
        False in realtime (newest message only, see :data:`REALTIME_QOS`).
    """
    return LOCKSTEP_QOS if lockstep else REALTIME_QOS


def reader_qos(publishers, depth):
    """
    Return a recorder's QoS that matches every publisher in ``publishers`` (their infos).

    Reliable unless one publisher is best effort; transient local only when all are (a
    latched state then arrives at once); KEEP_LAST ``depth``.
    """
    rel, dur = ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE
    if any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in publishers):
        rel = ReliabilityPolicy.BEST_EFFORT
    if publishers and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                          for i in publishers):
        dur = DurabilityPolicy.TRANSIENT_LOCAL
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=rel,
                      durability=dur)
