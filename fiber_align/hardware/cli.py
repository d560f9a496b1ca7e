# SPDX-License-Identifier: Apache-2.0
"""
``fiber-align emulate``: an MDT693B and a PM100 emulator on one simulated bench.

Prints one JSON line (``serial_port``: the pty, ``serial_link``: a stable symlink to it,
``visa_resource``, ``slot_position_m``, ``seed``, ``pid``, ...) and serves until SIGINT
or SIGTERM (or until the process that started it is gone), then stops both emulators and
exits 0. On SIGUSR1 it prints one JSON line of the truth now (``{"truth": ...}``:
:meth:`~fiber_align.hardware.emulators.physics.Bench.truth`). ``--array``: the fiber
array, one MDT693B (x, y_left, y_right on x, y, z) and two PM100s (``visa_resource``
``A,B``: channel 1's, channel N's). Defaults: ``config/hardware.yaml`` (section ``emulator``) and
``config/plant.yaml`` / ``config/optics.yaml``. Bad options exit 2 with one line.
"""

import json
import math
import os
import signal
import sys
import time

from fiber_align import lifeline
from fiber_align.hardware.bench import emulated
from fiber_align.hardware.mdt693b import LIMIT_SWITCHES_V


def register(subparsers):
    """Add the ``emulate`` sub-command."""
    p = subparsers.add_parser(
        'emulate', help='serve an emulated MDT693B (pty) and PM100 (TCP) on one bench',
        description='Start an MDT693B piezo amplifier emulator on a pseudo-terminal and a '
                    'PM100 power meter emulator on a loopback TCP socket, both on this '
                    "package's simulated bimorph and optics; print one JSON line and serve "
                    'until SIGINT or SIGTERM. Values in SI units (m, m/s, V, s).')
    # strings, checked in _run, so a bad value is one line and exit 2
    p.add_argument('--slot', metavar='M', help='slot (output core) position (m), '
                   'default config/optics.yaml')
    p.add_argument('--drift', metavar='M_PER_S', help='slot drift (m/s), default 0')
    p.add_argument('--seed', metavar='N', default='0', help='detector noise seed')
    p.add_argument('--model', metavar='MDT693B|MDT694B', help='amplifier model')
    p.add_argument('--v-limit', metavar='V', help='limit switch (V): 75, 100 or 150')
    p.add_argument('--echo', metavar='on|off', help='echo at power-on')
    p.add_argument('--pm100-port', metavar='PORT', help='TCP port, 0 = free one')
    p.add_argument('--link-dir', metavar='DIR', help='directory of the serial symlink')
    p.add_argument('--fiber-broken', action='store_true', help='no light anywhere')
    p.add_argument('--meter-floor', metavar='W', help='the PM100 clamps its readings at '
                   'this floor (W): a constant reading in the dark; default 0 (none)')
    p.add_argument('--meter-quantum', metavar='W', help='the PM100 rounds its readings '
                   'down to multiples of this (W): a quantised reading; default 0 (none)')
    p.add_argument('--rig', action='store_true', help='the two-axis rig: bimorphs on '
                   'channels x and y (--x-channel, --y-channel), 2-D optics')
    p.add_argument('--array', action='store_true', help='the fiber array: bimorphs x, '
                   'y_left, y_right on channels x, y, z, the array optics, two PM100s')
    p.add_argument('--target-x', metavar='M', help='rig: output core x (m), default '
                   "config/optics2d.yaml; array: the chip's x0 (config/array.yaml)")
    p.add_argument('--target-y', metavar='M', help="rig: output core y (m); array: y0")
    p.add_argument('--roll', metavar='RAD', help="array: the chip's roll0 (rad)")
    p.add_argument('--drift-y', metavar='M_PER_S', help='rig: target drift along y (m/s); '
                   '--drift is along x')
    p.add_argument('--x-channel', metavar='x|y|z', help='rig: channel of the x bimorph')
    p.add_argument('--y-channel', metavar='x|y|z', help='rig: channel of the y bimorph')
    # checked by fiber-align before _run (fiber_align.tools.paths)
    p.set_defaults(func=_run, paths={'--link-dir': 'in-dir'})


def _number(name, text, lo=-math.inf, hi=math.inf, integer=False):
    try:
        v = int(text) if integer else float(text)
    except (TypeError, ValueError):
        raise ValueError('%s must be %s, got %r' % (
            name, 'an integer' if integer else 'a number', text)) from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise ValueError('%s must be within %g..%g, got %r' % (name, lo, hi, text))
    return v


def options(args):
    """Check the options; return ``(seed, emulator overrides, optics overrides)``."""
    seed = _number('--seed', args.seed, 0, 2 ** 31 - 1, integer=True)
    emu, optics = {}, {}
    rig_only = [o for o, v in (('--target-x', args.target_x), ('--target-y', args.target_y),
                               ('--drift-y', args.drift_y), ('--x-channel', args.x_channel),
                               ('--y-channel', args.y_channel)) if v is not None]
    if args.array:
        bad = [o for o in rig_only if o not in ('--target-x', '--target-y')] + [
            o for o, v in (('--rig', args.rig), ('--slot', args.slot), ('--drift', args.drift))
            if v not in (None, False)]
        if bad:
            raise ValueError('%s: not available with --array' % ', '.join(bad))
        optics.update({k: _number(o, v, -lim, lim) for o, k, v, lim in (
            ('--target-x', 'chip_x_m', args.target_x, 1e-3),
            ('--target-y', 'chip_y_m', args.target_y, 1e-3),
            ('--roll', 'chip_roll_rad', args.roll, 0.1)) if v is not None}, layout_seed=seed)
        rig_only = []
    elif args.roll is not None:
        raise ValueError('--roll: only with --array')
    if rig_only and not args.rig:
        raise ValueError('%s: only with --rig' % ', '.join(rig_only))
    if args.rig and args.slot is not None:
        raise ValueError('--slot is 1-D; the rig takes --target-x and --target-y')
    if args.slot is not None:
        optics['slot_position_m'] = _number('--slot', args.slot, -1e-3, 1e-3)
    keys = {'--target-x': 'position_x_m', '--target-y': 'position_y_m',
            '--drift': 'drift_x_m_per_s' if args.rig else 'slot_drift_m_per_s',
            '--drift-y': 'drift_y_m_per_s'}
    for opt, text in (('--target-x', args.target_x), ('--target-y', args.target_y),
                      ('--drift', args.drift), ('--drift-y', args.drift_y)):
        if text is not None and not args.array:
            optics[keys[opt]] = _number(opt, text, -1e-3, 1e-3)
    for opt, key, text in (('--x-channel', 'rig_x_channel', args.x_channel),
                           ('--y-channel', 'rig_y_channel', args.y_channel)):
        if text is not None:
            if text not in ('x', 'y', 'z'):
                raise ValueError('%s must be x, y or z, got %r' % (opt, text))
            emu[key] = text
    if args.rig and args.x_channel is not None and args.x_channel == args.y_channel:
        raise ValueError('--x-channel and --y-channel name the same channel %r'
                         % args.x_channel)
    if args.fiber_broken:
        optics['fiber_broken'] = True
    for opt, key, text in (('--meter-floor', 'floor_w', args.meter_floor),
                           ('--meter-quantum', 'quantum_w', args.meter_quantum)):
        if text is not None:
            optics[key] = _number(opt, text, 0.0, 1e-3)
    if args.model is not None:
        if args.model not in ('MDT693B', 'MDT694B'):
            raise ValueError('--model must be MDT693B or MDT694B, got %r' % args.model)
        emu['model'] = args.model
        if (args.rig or args.array) and args.model == 'MDT694B':
            raise ValueError('%s needs %s channels; the MDT694B has x only'
                             % (('--array', 'three') if args.array else ('--rig', 'two')))
    if args.v_limit is not None:
        v = _number('--v-limit', args.v_limit)
        if v not in LIMIT_SWITCHES_V:
            raise ValueError('--v-limit must be 75, 100 or 150 (the switch), got %r'
                             % args.v_limit)
        emu['v_limit'] = v
    if args.echo is not None:
        if args.echo not in ('on', 'off'):
            raise ValueError('--echo must be on or off, got %r' % args.echo)
        emu['echo'] = args.echo == 'on'
    if args.pm100_port is not None:
        emu['pm100_port'] = _number('--pm100-port', args.pm100_port, 0, 65535, integer=True)
    if args.link_dir is not None:
        if not os.path.isdir(args.link_dir):
            raise ValueError('--link-dir %r is not a directory' % args.link_dir)
        emu['serial_link_dir'] = args.link_dir
    return seed, emu, optics


def _run(args):
    seed, emu, optics = options(args)
    stop = []       # a handler only appends: a lock taken there can deadlock the loop

    def on_signal(signum, frame):
        (asked if signum == signal.SIGUSR1 else stop).append(signum)

    asked = []
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM,
                                                    signal.SIGUSR1)}
    lifeline.watch_parent(lifeline.PARENT_PID, signal.SIGTERM)   # as on SIGTERM
    try:
        with emulated(seed=seed, emulator_params=emu, rig=args.rig, array=args.array,
                      **optics) as (bench, mdt, pm):
            meters = pm if isinstance(pm, list) else [pm]
            info = dict(serial_port=mdt.slave_path, serial_link=mdt.port,
                        visa_resource=','.join(m.resource for m in meters), model=mdt.model,
                        v_limit_v=bench.v_limit, echo=mdt.echo, seed=seed, pid=os.getpid())
            if args.array:
                c = bench.array
                info.update(array=True, axes=bench.axes, chip=list(c.chip),
                            layout_seed=seed, best_pose=list(c.best()))
            elif args.rig:
                t = bench.coupling2d.target
                info.update(rig=True, axes=bench.axes, target_x_m=t.p0[0], target_y_m=t.p0[1],
                            drift_x_m_per_s=t.v[0], drift_y_m_per_s=t.v[1])
            else:
                info.update(fiber_channel=bench.fiber_channel,
                            slot_position_m=bench.coupling.slot_position_m,
                            slot_drift_m_per_s=bench.coupling.slot_drift_m_per_s)
            print(json.dumps(info), flush=True)
            while not stop:
                if asked:
                    del asked[:]
                    print(json.dumps(dict(truth=bench.truth())), flush=True)
                time.sleep(0.05)
            stats = dict(stopped=True, mdt693b_commands=mdt.commands,
                         voltage_commands=len(mdt.command_log),
                         pm100_readings=sum(m.readings for m in meters))
            try:
                print(json.dumps(stats), file=sys.stderr, flush=True)
            except OSError:     # a launcher killed with SIGKILL took the reader along
                pass
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    return 0
