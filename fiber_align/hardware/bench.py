# SPDX-License-Identifier: Apache-2.0
"""
Sensorless alignment on a (real or emulated) bench: no displacement sensor.

One period ``k`` at wall time ``t_k`` (s), at ``rate_hz`` (``config/hardware.yaml``):

1. ``P_k`` = PM100 reading (W) through pyvisa (``MEAS:POW?``);
2. ``r_k`` = ``Sequencer.update(t_k, y_k, P_k)`` (m), with ``y_k`` the *commanded*
   displacement: the forward PI model of the voltage actually sent (after the clamp);
3. ``u_k`` = inverse PI feedforward of ``r_k`` (V), the compensator's model
   (``config/models/compensator_model.yaml``);
4. ``v_k`` = ``DriverCore.command(u_k, 0, t_k)``: clamp to ``[v_min, v_max]``, slew (V);
5. ``v_k`` goes to the MDT693B over the serial port (:class:`MDT693BOutput` refuses
   anything outside the limits again) and ``y_{k+1}`` = forward model of ``v_k``.

The inverse PI model is the only positioner: the optical power closes the alignment
loop through the sequencer (search, parabola fit of ``ln P``, dither tracking).

:func:`emulated` starts both emulators in this process on one
:class:`~fiber_align.hardware.emulators.physics.Bench`, so a run can also read the
truth (the loss against the true peak) for the checks. SI units throughout.
"""

import contextlib
import time

from fiber_align.alignment import sequencer as sq
from fiber_align.config import load_params
from fiber_align.control.driver import DriverCore
from fiber_align.control.feedforward import Feedforward
from fiber_align.hardware import errors as er
from fiber_align.hardware.emulators.mdt693b import MDT693BEmulator
from fiber_align.hardware.emulators.physics import ArrayBench, Bench, RigBench
from fiber_align.hardware.emulators.pm100 import PM100Emulator
from fiber_align.hardware.mdt693b_channels import MDT693BOutput
from fiber_align.hardware.pm100 import PM100
from fiber_align.hysteresis.pi import PIModel

CONFIG_FILE = 'hardware.yaml'
SEQUENCER_FILE = 'sequencer_hardware.yaml'


def load_hardware(node, path=CONFIG_FILE, **overrides):
    """Return the parameters of ``node`` in ``config/hardware.yaml``, ``overrides`` applied."""
    p = dict(load_params(path, node))
    p.update({k: v for k, v in overrides.items() if v is not None})
    return p


@contextlib.contextmanager
def emulated(seed=0, emulator_params=None, rig=False, array=False, **optics):
    """
    Start an MDT693B and a PM100 emulator on one bench; yield ``(bench, mdt, pm)``.

    ``array``: the fiber array (:class:`ArrayBench`: the holder on channels
    ``array_x_channel``, ``array_y_left_channel``, ``array_y_right_channel``, the array
    optics); ``pm`` is then a list of two PM100 emulators, channel 1's and channel N's
    (the second on ``pm100_port + 1`` when that is not 0).

    :param seed: detector noise seed.
    :param emulator_params: overrides of the ``emulator`` section of hardware.yaml.
    :param rig: the two-axis rig (:class:`RigBench`: the fiber on channels
        ``rig_x_channel`` and ``rig_y_channel``, the 2-D optics) instead of one axis.
    :param optics: optics overrides (1-D: ``slot_position_m``, ``slot_drift_m_per_s``,
        ...; rig: ``position_x_m``, ``position_y_m``, ``drift_x_m_per_s``, ...).
    """
    e = load_hardware('emulator', **(emulator_params or {}))
    if array:
        bench = ArrayBench(v_limit=float(e['v_limit']), seed=seed, step_s=float(e['step_s']),
                           axes={a: e['array_%s_channel' % a] for a in ArrayBench.AXES},
                           **optics)
    elif rig:
        bench = RigBench(v_limit=float(e['v_limit']), seed=seed, step_s=float(e['step_s']),
                         axes={'x': e['rig_x_channel'], 'y': e['rig_y_channel']}, **optics)
    else:
        bench = Bench(v_limit=float(e['v_limit']), fiber_channel=e['fiber_channel'],
                      seed=seed, step_s=float(e['step_s']), **optics)
    mdt = pm = None
    try:
        mdt = MDT693BEmulator(bench, model=e['model'], echo=bool(e['echo']),
                              link_dir=e.get('serial_link_dir') or None,
                              response_delay_s=float(e['response_delay_s']),
                              baud=int(e['baud']), turnaround_s=float(e['turnaround_s']))
        port = int(e['pm100_port'])
        if array:
            pm = []
            for j in range(2):
                pm.append(PM100Emulator(bench.meter(j), port=port + j if port else 0,
                                        sample_time_s=float(e['sample_time_s'])))
        else:
            pm = PM100Emulator(bench, port=port, sample_time_s=float(e['sample_time_s']))
        yield bench, mdt, pm
    finally:
        for m in (pm if isinstance(pm, list) else [pm]):
            if m is not None:
                m.stop()
        if mdt is not None:
            mdt.stop()


class SensorlessBench:
    """
    The sensorless loop of the module docstring on one MDT693B channel and one PM100.

    :param serial_port: the MDT693B's serial port.
    :param visa_resource: the PM100's VISA resource.
    :param hw: overrides of ``hardware_bench`` (``rate_hz``, ``slew_rate_v_per_s``,
        ``model_file``).
    :param driver: overrides of the ``actuator_driver`` section (channel, limits, ...).
    :param meter: overrides of the ``power_meter`` section.
    :param sequencer: sequencer parameters (default ``config/sequencer_hardware.yaml``).
    :param truth: optional callable returning the true loss (dB) now (emulator only).
    """

    def __init__(self, serial_port, visa_resource, hw=None, driver=None, meter=None,
                 sequencer=None, truth=None):
        """Build the parts; nothing is opened until :meth:`connect`."""
        self.hw = dict(load_params(CONFIG_FILE, '/**'),     # rate_hz: the hardware graph's
                       **load_hardware('hardware_bench', **(hw or {})))
        d = load_hardware('actuator_driver', port=serial_port, **(driver or {}))
        m = load_hardware('power_meter', resource=visa_resource, **(meter or {}))
        self.period_s = 1.0 / float(self.hw['rate_hz'])
        self.max_dt_s = float(self.hw['max_control_dt_s'])
        self.output = MDT693BOutput.from_params(d)
        self.meter = PM100.from_params(m)
        self.driver = DriverCore(float(d['v_min']), float(d['v_max']),
                                 float(self.hw['slew_rate_v_per_s']), 0.0,
                                 float(d['safe_voltage_v']))
        self.model = PIModel.load(self.hw['model_file'], 'hysteresis_compensator')
        self.ff = Feedforward(self.model)
        self.forward = PIModel(self.model.thresholds, self.model.weights)
        params = sequencer if sequencer is not None else load_params(
            SEQUENCER_FILE, sq.CONFIG_NODE)
        self.seq = sq.Sequencer(params)
        self.truth = truth
        self.y_cmd = 0.0
        self.t0 = None
        self.t_wall = None
        self.t_ctrl = 0.0
        self.trace = []
        self.overruns = 0
        self.steps = 0

    def connect(self):
        """Configure the amplifier (identify, limit check) and the meter; return their info."""
        a = self.output.configure()
        self.meter.open()
        b = self.meter.configure()
        self.driver.reset()
        self.ff.reset()
        self.forward.reset()
        self.y_cmd = 0.0
        return dict(amplifier=a, meter=b)

    def close(self):
        """Ramp the amplifier to the safe voltage (if reachable) and close both devices."""
        try:
            if self.output.connected and self.output.device_limit_v is not None:
                self.output.ramp_to()
        except er.DeviceError:
            pass
        self.output.close()
        self.meter.close()

    def now(self):
        """
        Return the control time (s): wall time since the first step, gaps capped.

        A period that overran (a starved CPU, a slow device) advances the control time by
        at most ``max_control_dt_s``, so the sequencer's per-period moves (speed x dt)
        stay at the configured resolution instead of jumping.
        """
        w = time.monotonic()
        if self.t_wall is None:
            self.t0 = self.t_wall = w
            return self.t_ctrl
        self.t_ctrl += min(max(w - self.t_wall, 0.0), self.max_dt_s)
        self.t_wall = w
        return self.t_ctrl

    def step(self):
        """Run one period now; return ``(t_s, power_w, setpoint_m, volts)`` (control time)."""
        t = self.now()
        p = self.meter.read_w()
        r = self.seq.update(t, self.y_cmd, p)
        u = self.ff.step(r)
        v = self.driver.command(u, 0.0, t)
        self.output.write(v)
        self.y_cmd = self.forward.step(v)
        self.steps += 1
        row = (t, p, r, v)
        if self.truth is not None:
            self.trace.append(row + (self.seq.state, self.truth()))
        return row

    def run(self, until, timeout_s):
        """
        Step at ``rate_hz`` until ``until(self)`` is true or ``timeout_s`` (s) of wall time.

        Returns True when ``until`` was met. A step that overruns its period is counted in
        :attr:`overruns` and the next one starts at once.
        """
        t_next = time.monotonic()
        end = t_next + timeout_s
        while True:
            self.step()
            if until(self):
                return True
            t_next += self.period_s
            now = time.monotonic()
            if now >= end:
                return False
            if t_next > now:
                time.sleep(t_next - now)
            else:
                self.overruns += 1
                t_next = now

    # -- scenarios ---------------------------------------------------------------------------
    def align(self, timeout_s=3.0):
        """Command ``align`` and run until TRACKING or FAULT; return ``(ok, wall s)``."""
        t0 = time.monotonic()
        self.seq.align()
        self.run(lambda b: b.seq.state in (sq.TRACKING, sq.FAULT), timeout_s)
        return self.seq.state == sq.TRACKING, time.monotonic() - t0

    def hold(self, seconds):
        """Keep stepping for ``seconds`` (s) of wall time; return the true losses (dB)."""
        n0 = len(self.trace)
        self.run(lambda b: b.seq.state == sq.FAULT, seconds)
        return [row[5] for row in self.trace[n0:] if row[4] == sq.TRACKING]

    def switch(self, on, timeout_s=2.0):
        """Switch off (until IDLE) or on (until TRACKING); return ``(ok, wall s)``."""
        t0 = time.monotonic()
        ok, msg = self.seq.switch(on)
        if not ok:
            return False, msg
        goal = sq.TRACKING if on else sq.IDLE
        self.run(lambda b: b.seq.state in (goal, sq.FAULT), timeout_s)
        return self.seq.state == goal, time.monotonic() - t0


def align_trial(seed, slot_m, timeout_s=3.0, settle_s=0.2, rest_s=0.15, **bench_kw):
    """
    Align once on fresh emulators with the slot at ``slot_m`` (m); return SI metrics.

    ``final_loss_db`` is the mean true loss over the first ``settle_s`` (s) of TRACKING
    (dither included); ``align_wall_s`` the wall time from ``align`` to TRACKING.
    """
    with emulated(seed=seed, slot_position_m=slot_m) as (bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource, truth=bench.true_loss_db, **bench_kw)
        try:
            sb.connect()
            sb.run(lambda b: False, rest_s)           # IDLE readings: the floor
            ok, wall = sb.align(timeout_s)
            losses = sb.hold(settle_s) if ok else []
            return dict(seed=seed, slot_m=slot_m, aligned=ok, align_wall_s=wall,
                        state=sb.seq.state, fault_reason=sb.seq.fault_reason,
                        final_loss_db=(sum(losses) / len(losses)) if losses else None,
                        max_loss_db=max(losses) if losses else None,
                        peak_samples=sb.seq.peak_samples, overruns=sb.overruns,
                        steps=sb.steps, commands=len(mdt.command_log))
        finally:
            sb.close()
