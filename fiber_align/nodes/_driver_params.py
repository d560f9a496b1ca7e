# SPDX-License-Identifier: Apache-2.0
"""
The parameters of ``actuator_driver``: one table per group, their declaration and checks.

:class:`DriverParameters` is a mixin of the node: the field-limit and consistency checks
and the live updates of the limits (:meth:`fiber_align.control.driver.DriverCore.
set_limits`). SI units (V, s, V/s).
"""

from fiber_align.config import ConfigError, load_params
from fiber_align.control.driver import check_field_limits, DriverCore
from fiber_align.graph.checks import protections_off
from fiber_align.hardware.mdt693b import CHANNELS
from fiber_align.nodes.ros.params import check_parameters, declare, declare_graph_values, PRIORITY

BACKENDS = ('topic', 'mdt693b')
#: The file of the ``mdt693b`` backend's settings: its ``actuator_driver`` section, and
#: the device address ``port`` under ``/**`` (where a command line's ``-p`` wins).
HARDWARE_FILE = 'hardware.yaml'
#: Keys of :data:`HARDWARE_FILE` the node declares whatever the backend (they only
#: matter for the ``mdt693b`` backend).
DEVICE_KEYS = ('port', 'channel', 'baud', 'device_limit_v', 'device_timeout_s',
               'ramp_rate_v_per_s', 'ramp_step_s', 'readback_period_s')
DEVICE_DOCS = {  # name: (description with unit, low, high) for the read-only parameters
    'port': ('serial device of the MDT693B (a /dev/serial/by-id link survives re-plugging)',
             None, None),
    'channel': ('amplifier channel driving the bimorph', None, None),
    'baud': ('serial rate (baud)', 1200, 4000000),
    'device_limit_v': ('limit switch of the amplifier (V); 0: read it (vlimit?) at '
                       'configure; > 0: must equal the device', 0.0, 1000.0),
    'device_timeout_s': ('no prompt within this (s) is a lost device', 0.01, 10.0),
    'ramp_rate_v_per_s': ('rate of the ramp to the safe voltage on deactivate and '
                          'shutdown (V/s)', 1e-3, 1e6),
    'ramp_step_s': ('time between two commands of that ramp (s)', 1e-3, 1.0),
    'readback_period_s': ('period of the read-back (xvoltage?) published on '
                          'drive_voltage_readback (s)', 0.005, 60.0),
}
CORE_KEYS = ('v_min', 'v_max', 'slew_rate_v_per_s', 'watchdog_timeout_s', 'safe_voltage_v',
             'latch_trips', 'latch_window_s', 'safe_ramp_rate_v_per_s')
LIMIT_KEYS = ('field_limit_v', 'coercive_field_v', 'depoling_fraction')
RANGES = {'v_min': (-1000.0, 1000.0), 'v_max': (-1000.0, 1000.0),
          'slew_rate_v_per_s': (-1.0, 1e12), 'watchdog_timeout_s': (0.0, 60.0),
          'safe_voltage_v': (-1000.0, 1000.0), 'latch_trips': (0, 1000),
          'latch_window_s': (0.0, 3600.0), 'safe_ramp_rate_v_per_s': (-1.0, 1e12)}
UNITS = {'v_min': 'lowest drive (V)', 'v_max': 'highest drive (V)',
         'slew_rate_v_per_s': 'slew limit (V/s); <= 0: none',
         'watchdog_timeout_s': 'silence before the safe ramp (s); 0: off',
         'safe_voltage_v': 'safe (light-off) drive (V)',
         'latch_trips': 'watchdog trips within latch_window_s that latch the safe '
                        'voltage (0: never)',
         'latch_window_s': 'window of the latch count (s)',
         'safe_ramp_rate_v_per_s': 'rate of every ramp to the safe voltage (V/s); <= 0: '
                                   'the slew limit'}
#: Read-only settings of the node: name -> (description, low, high, choices).
SETTINGS = {
    'backend': ('where the drive goes: topic (drive_voltage, the simulated actuator) or '
                'mdt693b (also a Thorlabs MDT693B channel)', None, None, BACKENDS),
    'field_limit_v': ('forward field limit of the PZT layers (V)', 0.0, 1000.0, None),
    'coercive_field_v': ('coercive field times layer thickness (V)', 0.0, 10000.0, None),
    'depoling_fraction': ('reverse drive allowed, as a fraction of coercive_field_v (1)',
                          0.0, 1.0, None),
}


def backend_defaults(backend):
    """
    Return the defaults a backend brings over ``driver.yaml``'s (the simulated actuator's).

    ``mdt693b``: every key of the ``actuator_driver`` section of :data:`HARDWARE_FILE`
    but ``backend`` (its limits: ``v_min`` 0 V, ``v_max`` the limit switch setting, the
    device settings), and ``port`` from its ``/**`` section; ``topic``: the device keys
    alone (declared, unused).
    """
    hw = load_params(HARDWARE_FILE, 'actuator_driver')
    hw['port'] = load_params(HARDWARE_FILE, '/**')['port']
    if backend != 'mdt693b':
        return {k: hw[k] for k in DEVICE_KEYS}
    hw.pop('backend', None)
    return hw


def declare_all(node, d):
    """
    Declare every parameter of the driver on ``node`` (defaults ``d``, then the backend's).

    ``backend`` is declared first; the defaults of the backend it names
    (:func:`backend_defaults`) then replace those of ``d``; a value the user sets (``-p``,
    a params file) wins over both.

    :param d: the node's defaults (``driver.yaml`` and ``fiber_align.yaml``).
    """
    d = dict(d)
    declare_graph_values(node, d, 'rate_hz', 'sync_mode', 'sensorless',
                         'diagnostics_period_s', *PRIORITY)
    for k, (text, lo, hi, choices) in SETTINGS.items():
        v = declare(node, d, k, text, lo, hi, True, choices=choices)
        if k == 'backend':
            d.update(backend_defaults(v))
    for k in CORE_KEYS:
        declare(node, d, k, UNITS[k], *RANGES[k])
    for k in DEVICE_KEYS:
        text, lo, hi = DEVICE_DOCS[k]
        declare(node, d, k, text, lo, hi, True,
                choices=CHANNELS if k == 'channel' else None)


class DriverParameters:
    """The limit parameters of ``ActuatorDriverNode``: checks and live updates (mixin)."""

    def _core_params(self, overrides=None):
        p = {k: self.get_parameter(k).value for k in CORE_KEYS + LIMIT_KEYS}
        p.update(overrides or {})
        return p

    def _check_core(self, p):
        """Return ``None`` or the reason why ``p`` is not a valid driver set-up."""
        why = check_field_limits(p)
        if why:
            return why
        try:
            DriverCore.from_params(p)
        except (ConfigError, ValueError) as exc:
            return str(exc)
        return None

    def _on_set(self, params):
        """Accept live updates of the limits when in range and consistent."""
        res = check_parameters(params, RANGES)
        if not res.successful:
            return res
        new = {p.name: float(p.value) for p in params if p.name in CORE_KEYS}
        if 'latch_trips' in new:
            new['latch_trips'] = int(new['latch_trips'])
        if new:
            p = self._core_params(new)
            why = self._check_core(p)
            if why:
                res.successful = False
                res.reason = why
                return res
            if self.core is not None:
                self.core.set_limits(new)
            self._report_protections(p)
        return res

    def _report_protections(self, p):
        """Report each protection ``p`` turns off: a WARN in the log and on /diagnostics."""
        off = protections_off(p)
        before = getattr(self, '_protections_off', {})
        for name, text in off.items():
            if before.get(name) != text:
                self.get_logger().warning('protection off: %s' % text)
        for name in before:
            if name not in off:
                self.get_logger().info('protection on again: %s=%r' % (name, p[name]))
        self._protections_off = off
        self.health.condition('protections', 'protection off: %s' % '; '.join(
            off.values()) if off else None)
