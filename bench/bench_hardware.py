# SPDX-License-Identifier: Apache-2.0
"""
The sensorless hardware bench on the emulators (docs/hardware.md).

- Rates of the emulated devices through pyserial (MDT693B ``xvoltage=`` and
  ``xvoltage?``) and pyvisa (PM100 ``MEAS:POW?`` at averaging 1 and 3), and of one
  loop period (one reading, one command).
- 20 seeds, slot uniform in 3..62 um: align within 0.1 dB of the true peak in <= 3 s of
  wall time, sensorless at ``rate_hz`` (100 Hz).
- 60 s of TRACKING under a 0.2 um/s slot drift: largest true loss (< 0.2 dB wanted).
- 10 switch off/on cycles: no FAULT, the loss after each.
- Unplug latency: amplifier pty closed / meter socket dropped to the typed error.

``python -m bench bench_hardware`` (``main(['--quick'])``: 5 seeds, 10 s of tracking).
``python -m bench.bench_hardware --rig --slots N [--track S]``: the two-axis rig on one
emulated MDT693B through the ROS graph (``bringup --rig --hardware``'s processes): the
link's achieved command rate against the emulator's timing (separate and combined
writes), N random targets in the reachable square aligned on fresh emulators (loss
against the true peak, wall time from ``align`` to TRACKING, readings, link rate), the
samples of the 2-D sequencer and of the hill climb at the same 100 Hz on ideal positioning,
and optionally S s of tracking under a 0.2 um/s drift on both axes.
``python -m bench.bench_hardware --graph [--seeds N]``: the same 20 alignments through the
ROS graph instead (``bringup --hardware``'s processes: sequencer, compensator and driver
in one process, power_meter, lifecycle_manager), each on fresh emulators (about 6 s each).
"""

import argparse
import sys
import threading
import time

import numpy as np

from fiber_align.hardware import errors as er
from fiber_align.hardware.bench import align_trial, emulated, SensorlessBench
from fiber_align.alignment import hillclimb2d as hc, sequencer2d as s2d
from fiber_align.config import load_params
from fiber_align.graph.hardware import build_hardware
from fiber_align.graph.hardware_rig import build_hardware_rig
from fiber_align.hardware.mdt693b_channels import MDT693BChannels
from fiber_align.bringup.hardware import ALIGN_TIMEOUT_S, HardwareRun
from fiber_align.plant.optics2d import OpticalLink2D
from fiber_align.simulation.alignment2d_scenarios import random_target


def _rate(fn, n):
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return n / (time.perf_counter() - t0)


def rates(n=2000):
    """Measure how fast (Hz) the emulated devices take commands and readings."""
    out = {}
    with emulated(seed=0, slot_position_m=30e-6) as (bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource)
        sb.connect()
        vals = iter(np.linspace(0.0, 50.0, n))
        out['mdt693b_set_hz'] = _rate(lambda: sb.output.write(float(next(vals))), n)
        out['mdt693b_read_hz'] = _rate(sb.output.read_back, n)
        out['pm100_meas_avg1_hz'] = _rate(sb.meter.read_w, 200)
        sb.meter.write('SENS:AVER:COUN 3')
        out['pm100_meas_avg3_hz'] = _rate(sb.meter.read_w, 100)
        sb.meter.write('SENS:AVER:COUN 1')
        out['loop_step_hz'] = _rate(sb.step, 200)
        sb.close()
    return out


def align_trials(n_seeds, trial=None):
    """Run ``n_seeds`` alignments (``trial``: the pure loop by default); return results."""
    res = []
    for seed in range(n_seeds):
        slot = float(np.random.default_rng(1000 + seed).uniform(3e-6, 62e-6))
        res.append(trial(seed, slot) if trial else align_trial(seed, slot, timeout_s=3.0))
    return res


def graph_trial(seed, slot_m=None, target_m=None, composed=None, settle_s=0.2,
                timeout_s=ALIGN_TIMEOUT_S, emulator_params=None, overrides=None):
    """
    Align once through a hardware graph on fresh in-process emulators; return SI metrics.

    The 1-D bench with the slot at ``slot_m`` (m), or with ``target_m`` (the output core
    ``(x, y)``, m) the two-axis rig on one MDT693B. ``final_loss_db``: the mean true loss
    (the emulator's truth) over the first ``settle_s`` (s) of TRACKING, as
    :func:`fiber_align.hardware.bench.align_trial`; ``align_wall_s``: wall time (s) from
    the ``align`` call to TRACKING; ``v_range``: the lowest and highest voltage the
    emulated amplifier received (V; the rig: on the axes' channels). The rig adds
    ``commands`` per channel, the link's achieved write rate (``link_rate_hz``: voltage
    commands a second between ``align`` and TRACKING, a combined one counted once), the
    amplifier's diagnostics and watchdog trips.
    """
    rig = target_m is not None
    optics = dict(position_x_m=target_m[0], position_y_m=target_m[1]) if rig else dict(
        slot_position_m=slot_m)
    with emulated(seed=seed, emulator_params=emulator_params, rig=rig, **optics) as (
            bench, mdt, pm):
        hw = HardwareRun((build_hardware_rig if rig else build_hardware)(
            port=mdt.port, visa_resource=pm.resource, composed=composed, overrides=overrides))
        try:
            hw.start()
            t0 = time.monotonic()
            ok, wall = hw.align(timeout_s)
            t1 = time.monotonic()
            losses = []
            end = time.monotonic() + settle_s
            while ok and time.monotonic() < end:
                losses.append(bench.true_loss_db())
                time.sleep(0.01)
            log = list(mdt.command_log)
            sent = [row[3] for row in log if not rig or row[1] in bench.axes.values()]
            out = dict(seed=seed, aligned=ok, align_wall_s=wall, status=dict(hw.status),
                       peak_samples=hw.status.get('peak_samples'),
                       final_loss_db=sum(losses) / len(losses) if losses else None,
                       max_loss_db=max(losses) if losses else None,
                       v_range=(min(sent), max(sent)) if sent else None)
            if not rig:
                out.update(slot_m=slot_m, commands=len(sent))
            else:
                during = {(row[0], row[2]) for row in log if t0 <= row[0] <= t1}
                out.update(target_m=tuple(target_m), diag=hw.diag.get(hw.driver),
                           commands={ch: sum(1 for r in log if r[1] == ch) for ch in 'xyz'},
                           link_rate_hz=len(during) / (t1 - t0) if t1 > t0 else None,
                           trips='%s, %s' % tuple((hw.obs.watch.latest.get(a) or {}).get(
                               'watchdog_count', '-') for a in ('x', 'y')))
        finally:
            codes = hw.stop()
        out['exit_codes'], out['children'] = codes, hw.summary.get('children', {})
        return out


def graph_track_switch(track_s, n_cycles, drift=0.2e-6, seed=5, slot_m=30e-6):
    """
    Align, track and switch through the ROS graph; return true losses (dB) and timings (s).

    Tracks ``track_s`` s under ``drift`` (m/s), then switches off and on ``n_cycles`` times.
    """
    with emulated(seed=seed, slot_position_m=slot_m, slot_drift_m_per_s=drift) as (
            bench, mdt, pm):
        hw = HardwareRun(build_hardware(port=mdt.port, visa_resource=pm.resource))
        try:
            hw.start()
            ok, wall = hw.align()
            x0 = bench.slot_position_m()
            losses = []
            end = time.monotonic() + (track_s if ok else 0.0)
            while time.monotonic() < end and hw.status.get('state') == 'TRACKING':
                losses.append(bench.true_loss_db())
                time.sleep(0.01)
            moved = bench.slot_position_m() - x0
            state = hw.status.get('state')
            cycles = []
            for _ in range(n_cycles if state == 'TRACKING' else 0):
                off, t_off = hw.switch(False)
                dark = bench.true_loss_db()
                on, t_on = hw.switch(True)
                time.sleep(0.2)
                cycles.append((off and on, dark, t_on, bench.true_loss_db()))
            return dict(aligned=ok, align_wall_s=wall, moved_m=moved, state=state,
                        fault=hw.status.get('fault_reason'), losses=losses, cycles=cycles,
                        final_state=hw.status.get('state'))
        finally:
            hw.stop()


def graph_main(n_seeds, track_s=60.0, n_cycles=10):
    """Align ``n_seeds`` times through the ROS graph; print a table; return 0."""
    t0 = time.time()
    trials = align_trials(n_seeds, graph_trial)
    print('| seed | slot (um) | state | loss (dB) | max loss (dB) | align wall (s) '
          '| peak samples | commands |')
    print('|---|---|---|---|---|---|---|---|')
    for t in trials:
        print('| %d | %.2f | %s | %s | %s | %.3f | %d | %d |' % (
            t['seed'], t['slot_m'] * 1e6, t['status'].get('state'),
            '-' if t['final_loss_db'] is None else '%.4f' % t['final_loss_db'],
            '-' if t['max_loss_db'] is None else '%.4f' % t['max_loss_db'],
            t['align_wall_s'], t['status'].get('peak_samples', 0), t['commands']))
    good = [t for t in trials if t['aligned'] and t['final_loss_db'] < 0.1
            and t['align_wall_s'] <= 3.0]
    walls = [t['align_wall_s'] for t in trials]
    print('\ngraph: aligned within 0.1 dB in <= 3 s: %d/%d; worst loss %.4f dB; align '
          'wall median %.3f s, worst %.3f s (%.0f s wall in all)'
          % (len(good), len(trials), max(t['final_loss_db'] or 99.0 for t in trials),
             float(np.median(walls)), max(walls), time.time() - t0))
    r = graph_track_switch(track_s, n_cycles)
    ls = r['losses']
    print('graph: track %.0f s at 0.2 um/s (slot moved %.2f um): max loss %s dB, mean %s dB, '
          'state %s %s' % (track_s, r['moved_m'] * 1e6,
                           '%.4f' % max(ls) if ls else '-',
                           '%.4f' % (sum(ls) / len(ls)) if ls else '-',
                           r['state'], r['fault'] or ''))
    cy = r['cycles']
    print('graph: %d switch cycles: %d without fault (final state %s); dark loss min %s dB; '
          'on-to-TRACKING max %s s; loss 0.2 s after on max %s dB (%.0f s wall in all)' % (
              len(cy), sum(1 for c in cy if c[0]), r['final_state'],
              '%.1f' % min(c[1] for c in cy) if cy else '-',
              '%.3f' % max(c[2] for c in cy) if cy else '-',
              '%.4f' % max(c[3] for c in cy) if cy else '-', time.time() - t0))
    return 0


def track(duration_s, drift=0.2e-6, seed=5):
    """Align with the slot at 20 um, then track a drifting slot; return SI metrics."""
    with emulated(seed=seed, slot_position_m=20e-6, slot_drift_m_per_s=drift) as (
            bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource, truth=bench.true_loss_db)
        try:
            sb.connect()
            sb.run(lambda b: False, 0.15)
            ok, wall = sb.align()
            s0 = bench.slot_position_m()
            losses = sb.hold(duration_s) if ok else []
            return dict(aligned=ok, state=sb.seq.state, fault=sb.seq.fault_reason,
                        max_loss_db=max(losses) if losses else None,
                        mean_loss_db=float(np.mean(losses)) if losses else None,
                        samples=len(losses), slot_moved_m=bench.slot_position_m() - s0,
                        overruns=sb.overruns, steps=sb.steps)
        finally:
            sb.close()


def switch_cycles(n, seed=6, slot_m=40e-6):
    """Align, then ``n`` off/on cycles; return per-cycle losses (dB) and on times (s)."""
    with emulated(seed=seed, slot_position_m=slot_m) as (bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource, truth=bench.true_loss_db)
        try:
            sb.connect()
            sb.run(lambda b: False, 0.15)
            ok, _ = sb.align()
            cyc = []
            faults = []
            for _ in range(n if ok else 0):
                ok_off, _ = sb.switch(False)
                dark = bench.true_loss_db()
                ok_on, wall = sb.switch(True)
                losses = sb.hold(0.2)
                cyc.append((dark, wall, max(losses) if losses else None))
                if not (ok_off and ok_on):
                    faults.append(sb.seq.fault_reason or sb.seq.state)
            return dict(aligned=ok, cycles=cyc, faults=faults, state=sb.seq.state)
        finally:
            sb.close()


def unplug_latency():
    """Return the time (s) from unplugging to the typed error, and its text, per device."""
    out = {}
    with emulated(seed=0) as (bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource)
        sb.connect()
        for name, dev, fn in (('mdt693b', mdt, lambda: sb.output.write(10.0)),
                              ('pm100', pm, sb.meter.read_w)):
            box = {}

            def go(dev=dev):
                box['t'] = time.monotonic()
                dev.unplug()
            threading.Timer(0.1, go).start()
            end = time.monotonic() + 3.0
            while time.monotonic() < end:
                try:
                    fn()
                except er.DeviceError as exc:
                    out[name] = (time.monotonic() - box['t'], str(exc))
                    break
                time.sleep(0.01)
        sb.close()
    return out


def link_rates(n=300):
    """
    Return the MDT693B link's achieved and modelled command rates (Hz) for two axes.

    Modelled: the emulator's timing, ``10 * bytes / baud`` for the command and its
    prompt plus the firmware turnaround, per transaction.
    """
    e = load_params('hardware.yaml', 'emulator')
    byte_s, turn = 10.0 / float(e['baud']), float(e['turnaround_s'])
    axes = {a: dict(channel=a, v_min=0.0, v_max=100.0, safe_voltage_v=0.0) for a in 'xy'}
    out = {}
    with emulated(seed=0, rig=True) as (bench, mdt, pm):
        for combined in (False, True):
            dev = MDT693BChannels(mdt.port, axes, combined=combined)
            dev.configure()
            vals = iter(np.linspace(0.0, 50.0, n))

            def pair():
                v = float(next(vals))
                dev.write({'x': v, 'y': 50.0 - v})
            name = 'xyzvoltage' if combined else 'xvoltage+yvoltage'
            out[name + '_pairs_hz'] = _rate(pair, n)
            cmds = (['xyzvoltage=12.345,23.456,0.000'] if combined
                    else ['xvoltage=12.345', 'yvoltage=23.456'])
            out[name + '_model_hz'] = 1.0 / sum((len(c) + 2) * byte_s + turn for c in cmds)
            dev.ramp_to_safe()
            dev.close()
    return out


def offline_samples(n, rate_hz=100.0):
    """
    Align ``n`` random targets with ideal positioning at ``rate_hz``; return the readings.

    The 2-D sequencer (hardware parameters) and the hill climb, each position the
    commanded one a period later (the sensorless loop with a perfect model).
    """
    base = dict(load_params(s2d.CONFIG_FILE, s2d.CONFIG_NODE))
    base.update(load_params('sequencer2d_hardware.yaml', s2d.CONFIG_NODE))
    period = 1.0 / rate_hz
    out = {'sequencer': [], 'hillclimb': []}
    for seed in range(n):
        tx, ty = random_target(1000 + seed)
        for method in out:
            link = OpticalLink2D.from_params(seed=seed, position_x_m=tx, position_y_m=ty)
            seq = (s2d.Sequencer2D(dict(base), period_s=period) if method == 'sequencer'
                   else hc.HillClimb2D(dict(base), period_s=period))
            x = y = 0.0
            k0 = None
            for k in range(int(20 * rate_hz)):
                t = k * period
                if k == 15:
                    seq.align()
                    k0 = k
                x, y = seq.update(t, x, y, link.measure(t, x, y, period))
                if k0 is not None and seq.status()['state'] in ('TRACKING', 'FAULT'):
                    break
            ok = seq.status()['state'] == 'TRACKING'
            out[method].append((ok, k - k0, link.loss_db(t, x, y)))
    return out


def rig_track(track_s, drift=0.2e-6, seed=7, target=(30e-6, 30e-6)):
    """Align the rig through the graph, then track a target drifting on both axes (dB)."""
    with emulated(seed=seed, rig=True, position_x_m=target[0], position_y_m=target[1],
                  drift_x_m_per_s=drift, drift_y_m_per_s=drift) as (bench, mdt, pm):
        hw = HardwareRun(build_hardware_rig(port=mdt.port, visa_resource=pm.resource))
        try:
            hw.start()
            ok, wall = hw.align()
            losses = []
            end = time.monotonic() + (track_s if ok else 0.0)
            while time.monotonic() < end and hw.status.get('state') == 'TRACKING':
                losses.append(bench.true_loss_db())
                time.sleep(0.01)
            return dict(aligned=ok, align_wall_s=wall, losses=losses,
                        state=hw.status.get('state'), fault=hw.status.get('fault_reason'))
        finally:
            hw.stop()


def rig_main(n_slots, track_s=0.0):
    """Run the two-axis rig on the emulators through the graph; print tables; return 0."""
    t0 = time.time()
    r = link_rates()
    print('MDT693B link, two axes a period (Hz): ' + ', '.join(
        '%s %.0f' % (k, v) for k, v in r.items()))
    print('\n| slot | target x, y (um) | state | loss (dB) | max loss (dB) | align wall (s) '
          '| peak samples | link commands/s | watchdog trips x, y |')
    print('|---|---|---|---|---|---|---|---|---|')
    trials = []
    for i in range(n_slots):
        target = random_target(1000 + i)
        t = graph_trial(seed=i, target_m=target)
        trials.append(t)
        print('| %d | %.1f, %.1f | %s | %s | %s | %.3f | %s | %s | %s |' % (
            i, target[0] * 1e6, target[1] * 1e6,
            t['status'].get('state') if t['aligned'] else '%s (%s)' % (
                t['status'].get('state'), t['status'].get('fault_reason')),
            '-' if t['final_loss_db'] is None else '%.4f' % t['final_loss_db'],
            '-' if t['max_loss_db'] is None else '%.4f' % t['max_loss_db'],
            t['align_wall_s'], t['peak_samples'],
            '-' if t['link_rate_hz'] is None else '%.1f' % t['link_rate_hz'],
            t.get('trips', '-')), flush=True)
    good = [t for t in trials if t['aligned'] and t['final_loss_db'] < 0.1]
    walls = [t['align_wall_s'] for t in trials]
    print('\nrig through the graph: %d/%d aligned within 0.1 dB of the true peak; align '
          'wall median %.3f s, worst %.3f s; link commands/s median %.1f (%.0f s wall)'
          % (len(good), len(trials), float(np.median(walls)), max(walls),
             float(np.median([t['link_rate_hz'] or 0.0 for t in trials])), time.time() - t0))
    off = offline_samples(max(n_slots, 5))
    for m, rows in off.items():
        ok = [k for a, k, loss in rows if a and loss < 0.1]
        print('offline, ideal positioning, 100 Hz, %s: %d/%d within 0.1 dB; readings from '
              'align to TRACKING median %s, worst %s' % (
                  m, len(ok), len(rows), int(np.median(ok)) if ok else '-',
                  max(ok) if ok else '-'))
    if track_s > 0:
        tr = rig_track(track_s)
        ls = tr['losses']
        print('rig: track %.0f s at 0.2 um/s on both axes: max loss %s dB, mean %s dB, '
              'state %s %s' % (track_s, '%.4f' % max(ls) if ls else '-',
                               '%.4f' % (sum(ls) / len(ls)) if ls else '-', tr['state'],
                               tr['fault'] or ''))
    print('(%.0f s wall)' % (time.time() - t0))
    return 0


def main(argv=None):
    """Run the checks and print tables; return 0."""
    ap = argparse.ArgumentParser(prog='bench_hardware')
    ap.add_argument('--quick', action='store_true', help='5 seeds, 10 s of tracking')
    ap.add_argument('--graph', action='store_true', help='the alignments through the ROS '
                    'graph (bringup --hardware) instead')
    ap.add_argument('--seeds', type=int, default=20, help='--graph: number of seeds')
    ap.add_argument('--rig', action='store_true', help='the two-axis rig on one MDT693B '
                    'through the ROS graph (bringup --rig --hardware)')
    ap.add_argument('--slots', type=int, default=20, help='--rig: random targets')
    ap.add_argument('--track', type=float, default=0.0, metavar='S',
                    help='--rig: then track S s under a 0.2 um/s drift on both axes')
    args = ap.parse_args([] if argv is None else argv)
    if args.rig:
        return rig_main(args.slots, args.track)
    if args.graph:
        return graph_main(*((5, 10.0, 3) if args.quick else (args.seeds, 60.0, 10)))
    n_seeds, track_s = (5, 10.0) if args.quick else (20, 60.0)
    t0 = time.time()
    r = rates()
    print('emulator rates through pyserial / pyvisa (Hz): ' + ', '.join(
        '%s %.0f' % (k, v) for k, v in r.items()))
    trials = align_trials(n_seeds)
    print('\n| seed | slot (um) | state | loss (dB) | align wall (s) | peak samples '
          '| overruns |')
    print('|---|---|---|---|---|---|---|')
    for t in trials:
        print('| %d | %.2f | %s | %s | %.3f | %d | %d |' % (
            t['seed'], t['slot_m'] * 1e6,
            t['state'] if t['aligned'] else '%s (%s)' % (t['state'], t['fault_reason']),
            '-' if t['final_loss_db'] is None else '%.4f' % t['final_loss_db'],
            t['align_wall_s'], t['peak_samples'], t['overruns']))
    good = [t for t in trials if t['aligned'] and t['final_loss_db'] < 0.1
            and t['align_wall_s'] <= 3.0]
    print('\naligned within 0.1 dB in <= 3 s: %d/%d; worst loss %.4f dB, worst wall %.3f s'
          % (len(good), len(trials),
             max(t['final_loss_db'] or 99.0 for t in trials),
             max(t['align_wall_s'] for t in trials)))
    tr = track(track_s)
    print('track %.0f s at 0.2 um/s (slot moved %.2f um): max loss %s dB, mean %s dB, '
          'state %s %s, overruns %d of %d periods' % (
              track_s, tr['slot_moved_m'] * 1e6,
              '-' if tr['max_loss_db'] is None else '%.4f' % tr['max_loss_db'],
              '-' if tr['mean_loss_db'] is None else '%.4f' % tr['mean_loss_db'],
              tr['state'], tr['fault'], tr['overruns'], tr['steps']))
    sw = switch_cycles(10)
    print('switch 10 cycles: faults %s; dark loss min %.1f dB; on time max %.3f s; loss '
          'after on max %.4f dB' % (
              sw['faults'] or 'none', min(c[0] for c in sw['cycles']),
              max(c[1] for c in sw['cycles']), max(c[2] for c in sw['cycles'])))
    for name, (dt, text) in unplug_latency().items():
        print('unplug %s: error after %.3f s: %s' % (name, dt, text))
    print('(%.0f s wall)' % (time.time() - t0))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
