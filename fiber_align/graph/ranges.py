# SPDX-License-Identifier: Apache-2.0
"""
Every parameter range a node declares, as data, and the check of a graph's values (pure).

One table per node that has ranges of its own, ``{name: (description, low, high)}``
(SI units in the description), beside the core tables the nodes already declare from
(:data:`fiber_align.control.driver_axes.RANGES` and ``SETTINGS``,
:data:`fiber_align.control.factory.PARAM_RANGES`,
:data:`fiber_align.hardware.mdt693b_session.DEVICE_DOCS`) and the graph-wide values
(:data:`GRAPH_VALUES`). The nodes declare from these tables (``nodes/ros/params.py``), and
:func:`range_of` answers the same question for the graph layer, so a params file is
checked against exactly what the nodes would refuse, before any process starts
(:func:`fiber_align.graph.refusals.check_graph`).
"""

import math

from fiber_align.control import driver_axes as da
from fiber_align.control.factory import CONTROLLERS, PARAM_RANGES
from fiber_align.control.trajectory import REALTIME_SETPOINT_RATE_M_PER_S
from fiber_align.graph.params import (
    AMPLIFIER, ARRAY_OPTICS, COMPENSATOR, CONTROLLER, DRIVER, flat, LIFECYCLE_MANAGER,
    LIVE_VIEW, OPTICS_2D, PLANT, RECORDER, RUN_CATALOG, SCENARIO_RUNNER, SEQUENCER,
    SEQUENCER_2D, STATION_OPTICS, STATION_SEQUENCER, SYNC_MODES)
from fiber_align.hardware.mdt693b_session import DEVICE_DOCS

#: The graph-wide values: name -> (description, low, high, choices, fallback). Every
#: node that uses one declares it read-only (``declare_graph_values``); the fallback
#: (``None``: none) serves a value the params files may not set.
GRAPH_VALUES = {
    'rate_hz': ('control rate (Hz)', 1.0, 20000.0, None, None),
    'sync_mode': ('sample pairing: index (lockstep) or latest (realtime)', None, None,
                  SYNC_MODES, None),
    'controller': ('control law (as in fiber-align simulate)', None, None, CONTROLLERS,
                   None),
    'sensorless': ('no displacement sensor: step once per setpoint, drive the '
                   'feedforward alone (bool)', None, None, None, None),
    'diagnostics_period_s': ('/diagnostics period (s)', 0.01, 60.0, None, None),
    'setpoint_min_m': ('lowest accepted setpoint (m)', -1e-3, 1e-3, None, None),
    'setpoint_max_m': ('highest accepted setpoint (m)', -1e-3, 1e-3, None, None),
    'realtime_setpoint_rate_m_per_s': (
        'realtime: rate limit of the setpoint trajectory (m/s); <= 0: none', -1.0, 10.0,
        None, REALTIME_SETPOINT_RATE_M_PER_S),
    'realtime_setpoint_accel_m_per_s2': (
        'realtime: acceleration limit of the setpoint trajectory (m/s^2); <= 0: none', -1.0,
        1e4, None, None),
    'cpu_idle_poll': ('with realtime_priority: hold /dev/cpu_dma_latency at 0 us while the '
                      'process runs, so idle CPUs poll instead of halting (bool; needs '
                      'root; refused: a WARN)', None, None, None, None),
    'lock_memory': ('with realtime_priority: lock the process memory in RAM (mlockall; '
                    'bool)', None, None, None, None),
    'realtime_priority': ('SCHED_FIFO priority of the executor thread (1..99); 0: normal '
                          'scheduling (needs root or an rtprio limit; refused: a WARN)', 0,
                          99, None, None),
    'publish_thread': ('realtime, composed: DDS publishes made by a thread of their own, '
                       'off the control thread (bool; docs/realtime.md)', None, None, None,
                       None),
}

#: The reference shaping and its design model (the compensator and the controller).
SHAPING = {
    'shaping_omega_n_rad_s': ('mode to suppress (rad/s); <= 0: the design model', -1.0, 1e6),
    'shaping_damping_ratio': ('damping ratio of that mode (1)', 0.0, 0.999),
    'delay_compensation_max_accel_m_per_s2': (
        'growth limit of the predicted reference rate (m/s^2)', 0.0, 1e6),
}

#: ``simulated_actuator``: the plant, its sensor and its sample clock.
PLANT_RANGES = {
    'omega_n_rad_s': ('first bending mode (rad/s); <= 0: design model', -1.0, 1e6),
    'damping_ratio': ('modal damping ratio (1)', 0.0, 0.999),
    'v_min': ('amplifier lower limit (V)', -200.0, 200.0),
    'v_max': ('amplifier upper limit (V)', -200.0, 200.0),
    'slew_rate_v_per_s': ('amplifier slew limit (V/s); <= 0: none', -1.0, 1e12),
    'noise_rms_m': ('sensor noise (m RMS)', 0.0, 1e-3),
    'resolution_m': ('sensor resolution (m)', 0.0, 1e-3),
    'seed': ('sensor noise seed', 0, 2 ** 31 - 1),
    'cycle_goal_missed_share': ('realtime: a loop that misses more than this share of its '
                                'periods in the last 10 s is a WARN on /diagnostics (1; '
                                'periods the driver holds are not counted); 0: no warning',
                                0.0, 1.0),
    'lockstep_timeout_s': ('lockstep: warn when no drive within this time (s)', 0.001,
                           3600.0),
    'start_wait_s': ('bound of that wait (s, wall)', 0.0, 3600.0),
    'optical_power_every': ('publish optical_power every N samples (1); 0: off (the '
                            'alignment sequencer needs 1)', 0, 1000000),
    'tip_position_every': ('publish tip_position (true tip position, m) every N samples; '
                           '0: off', 0, 1000000),
}

#: The simulated optics of several axes (the rig's, the station's).
OPTICS_RANGES = {'seed': ('detector noise seed', 0, 2 ** 31 - 1)}
#: ``simulated_array_optics``: also how often its model is published (0: never).
ARRAY_OPTICS_RANGES = dict(OPTICS_RANGES, model_period_s=(
    'the model\'s pose and per-channel coupling on array_model every this (s; 0: never)',
    0.0, 60.0))

#: ``hysteresis_compensator``'s own.
COMPENSATOR_RANGES = {
    'open_loop_gain_v_per_m': ('linear feedforward gain (V/m)', 0.0, 1e9),
}

#: ``fuzzy_pid_controller``'s own (its laws' keys: :data:`PARAM_RANGES`, by last name).
CONTROLLER_RANGES = {
    'controller_state_every': ('publish controller_state every N samples (1); 0: off', 0,
                               1000000),
}

#: ``scenario_runner``.
SCENARIO_RANGES = {
    'duration_s': ("length (s of sample time); 0: the scenario's own", 0.0, 1e6),
    'reach_m': ('largest reachable displacement (m); 0: unknown', 0.0, 1e-2),
    'recorder_wait_s': ('longest such wait (s)', 0.0, 600.0),
}

#: ``bag_recorder``.
RECORDER_RANGES = {
    'discovery_period_s': ('topic discovery period (s)', 0.01, 60.0),
    'queue_depth': ('reader history per topic (messages)', 1, 10_000_000),
    'flush_period_s': ('period of mcap chunk flushes (s)', 0.01, 60.0),
    'snapshots': ('folder of the flight recorder\'s snapshot bags ("": off)', None, None),
    'snapshot_before_s': ('s of a snapshot before its trigger', 0.1, 600.0),
    'snapshot_after_s': ('s of a snapshot after its trigger', 0.0, 600.0),
    'snapshot_max_bytes': ('bytes the rings of all topics keep at most', 2 ** 20, 2 ** 36),
}

#: ``lifecycle_manager``.
MANAGER_RANGES = {
    'service_timeout_s': ('bound on each wait for lifecycle services and on each call (s)',
                          0.1, 3600.0),
}

#: ``power_meter`` (every one read-only; ranges None: none).
POWER_METER_RANGES = {
    'resource': ('VISA resource (TCPIP::host::port::SOCKET, ASRL..., USB0::...)', None, None),
    'visa_backend': ('pyvisa backend (@py = pyvisa-py)', None, None),
    'averaging_count': ('SENS:AVER:COUN (samples of ~3 ms each)', 1, 10000),
    'wavelength_m': ('wavelength correction (m), sent in nm', 200e-9, 20e-6),
    'rate_hz': ('largest reading rate (Hz)', 0.1, 1000.0),
    'timeout_s': ('bound on every query (s); no reply = meter lost', 0.01, 10.0),
    'reconnect_period_s': ('time between reconnection attempts (s)', 0.05, 60.0),
    'diagnostics_period_s': ('period of /diagnostics (s)', 0.05, 60.0),
}

#: ``live_view`` (every one read-only; ranges None: none).
LIVE_VIEW_RANGES = {
    'host': ('address to listen on (127.0.0.1: this machine only; 0.0.0.0: every '
             'interface)', None, None),
    'port': ('TCP port of ws://host:port', 1, 65535),
    'topics': ('topics served as ROS 2 channels (relative names resolve in the '
               'namespace)', None, None),
    'state_topics': ('topics served message by message (the others: decimated)', None,
                     None),
    'extra_topics': ('further topics served when something publishes them', None, None),
    'ui_rate_hz': ('largest rate of each per-sample channel (Hz)', 0.1, 1000.0),
    'discovery_period_s': ('period of the look for new publishers (s)', 0.01, 60.0),
    'power_map': ('serve the 2-D power map of the search (the rig; bool)', None, None),
    'power_map_cell_m': ('power map cell side (m)', 1e-9, 1e-3),
    'power_map_period_s': ('period of the power map (s)', 0.01, 60.0),
    'power_map_queue_depth': ('messages queued per map topic between two looks', 1,
                              100000),
    'message_backlog': ('messages queued per client (oldest dropped)', 1, 1000000),
    'niceness': ('CPU niceness added to the process (os.nice; 0: none)', 0, 19),
}
#: ``run_catalog`` (every one read-only; ranges None: none; config/records.yaml).
CATALOG_RANGES = {
    'catalog': ('default, none, a SQLite path or postgresql://...', None, None),
    'queue_size': ('rows waiting for the writer at most', 1, 10 ** 7),
    'retry_period_s': ('retry period of a spooling writer (s)', 0.01, 3600.0),
    'connect_timeout_s': ('PostgreSQL connection attempt (s)', 0.01, 600.0),
    'busy_timeout_s': ('wait for a locked SQLite file (s)', 0.0, 600.0),
    'spool_dir': ("spool folder ('' = $ROS_HOME/fiber_align/spool)", None, None),
    'machine': ('the machine: 1d, rig, station, array', None, None),
    'hardware': ('real devices', None, None),
    'bag_path': ("the run's bag ('' = none)", None, None),
    'graph_parameters': ("every node's parameters, JSON", None, None),
    'reference_power_w': ('power of 0 dB loss (W); 0: no loss', 0.0, 1e3)}
#: The live view's power map range (m), each of these keys.
LIVE_VIEW_MAP = ('power map range (m)', -1e-2, 1e-2)

#: Unit and allowed range of a parameter, by the end of its name (SI; checked in order):
#: the sequencers' core parameters (``declare_si``).
SI_SUFFIXES = (
    ('_m_per_s', 'm/s', -1.0, 1.0), ('_rad_s', 'rad/s', 0.0, 1e7), ('_hz', 'Hz', 0.0, 1e6),
    ('_db', 'dB', -300.0, 300.0), ('_w', 'W', 0.0, 100.0), ('_m', 'm', -1e-2, 1e-2),
    ('_s', 's', 0.0, 3600.0), ('_samples', 'samples', 0, 10_000_000),
    ('_sigma', 'standard deviations', 0.0, 1e6), ('_refits', 'count', 0, 1000))


def si_range(name, value, what):
    """Return ``(description, low, high)`` of a core parameter by its name's unit, or None."""
    if isinstance(value, bool):
        return None
    for suffix, unit, lo, hi in SI_SUFFIXES:
        if name.endswith(suffix):
            return ('%s parameter (%s)' % (what, unit), lo, hi)
    return None


#: node (base name) -> its own table (looked up before :data:`GRAPH_VALUES`).
OWN = {PLANT: PLANT_RANGES, COMPENSATOR: dict(SHAPING, **COMPENSATOR_RANGES),
       CONTROLLER: dict(SHAPING, **CONTROLLER_RANGES), SCENARIO_RUNNER: SCENARIO_RANGES,
       RECORDER: RECORDER_RANGES, LIFECYCLE_MANAGER: MANAGER_RANGES,
       OPTICS_2D: OPTICS_RANGES, STATION_OPTICS: OPTICS_RANGES,
       ARRAY_OPTICS: ARRAY_OPTICS_RANGES,
       'power_meter': POWER_METER_RANGES, 'power_meter_n': POWER_METER_RANGES,
       LIVE_VIEW: LIVE_VIEW_RANGES, RUN_CATALOG: CATALOG_RANGES}
#: The driver nodes (one executable): per-axis limits, settings, device settings.
DRIVERS = (DRIVER, AMPLIFIER)
SEQUENCERS = (SEQUENCER, SEQUENCER_2D, STATION_SEQUENCER)


def _driver_range(name):
    key = name.rpartition('.')[2]
    if key in da.RANGES:
        return (da.UNITS[key],) + da.RANGES[key]
    if name in da.SETTINGS:
        return da.SETTINGS[name][:3]
    return DEVICE_DOCS.get(name)


def range_of(node, name, params=None, core=()):
    """
    Return ``(description, low, high)`` of parameter ``name`` of ``node``, or None.

    :param node: the node's base name (``simulated_actuator``, ``mdt693b_driver``, ...).
    :param name: the ROS (dotted) parameter name.
    :param params: the node's effective parameters (a sequencer's value of ``name``:
        a bool has no range); ``None``: none.
    :param core: a sequencer's core parameter names, declared by their unit
        (:func:`fiber_align.graph.refusals.core_keys`); ``()``: none.
    :returns: the range the node declares (low, high in SI; ``None`` each: no range), or
        ``None`` when the node declares no range for it.
    """
    row = OWN.get(node, {}).get(name)
    if row is None and name in GRAPH_VALUES:
        row = GRAPH_VALUES[name][:3]
    if row is None and node in DRIVERS:
        row = _driver_range(name)
    if row is None and node == CONTROLLER:
        key = name.rpartition('.')[2]
        row = ('controller parameter (SI, see controller.yaml)',) + PARAM_RANGES[key] \
            if key in PARAM_RANGES else None
    if row is None and node in SEQUENCERS and name in core:
        row = si_range(name, (params or {}).get(name), 'sequencer')
    if row is None and node == LIVE_VIEW and name.startswith('range_'):
        row = LIVE_VIEW_MAP
    return row if row is not None and row[1] is not None else None


def _numbers(value):
    """Return the numbers of a value (a list's entries), or ``()`` for bools and text."""
    vals = value if isinstance(value, (list, tuple)) else [value]
    if not vals or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in vals):
        return ()
    return vals


def range_refusal(node, params, label=None, core=()):
    """
    Return ``None`` or why one of ``node``'s values is out of its declared range (one line).

    :param node: the node's base name; ``params`` its effective parameters (nested).
    :param label: the node as the line names it (``/rig/x/actuator_driver``).
    :param core: a sequencer's core parameter names (:func:`range_of`).
    """
    for name, value in sorted(flat(params).items()):
        row = range_of(node, name, params, core)
        if row is None:
            continue
        text, lo, hi = row
        for v in _numbers(value):
            if not (math.isfinite(float(v)) and lo <= v <= hi):
                return '%s: %s=%r is out of range [%g, %g] (%s)' % (
                    label or node, name, value, lo, hi, text)
    return None
