# SPDX-License-Identifier: Apache-2.0
"""
Offline array scenario: the array sequencer (and its serial baseline) on three axes.

The rig is three independent closed loops (x, y_left, y_right: the control core's plant,
composite controller, driver and sensor noise, each its own seed), the link the array's
(:mod:`fiber_align.plant.array_optics`: eight channels, the two outer ones measured),
stepped by the one harness (:mod:`fiber_align.simulation.harness`).

``array``
    The chip's ideal pose drawn from the seed: ``x0`` and ``y0`` anywhere in the stroke
    that keeps both y actuators ``EDGE_M`` inside it, ``roll0`` uniform in
    ``+-ROLL_MAX_RAD``; the waveguides' errors and the channels' gains drawn from the seed
    (``layout_seed``). From IDLE at the nominal pose, ``align``. Figures (:func:`figures`):
    ``true`` and ``final`` (the chip's pose; the sequencer's aligned pose at the end of
    the loss window), ``worst_channel_loss_db`` (the worst channel at ``final`` against its
    coupling at the best joint pose), ``time_to_aligned_s`` (command to TRACKING, first
    light included), ``samples`` (readings in that time); the serial baseline's under
    ``baseline``, on the same chip, layout and seeds.
"""

import json
import sys

import numpy as np

from fiber_align.alignment import array as ar
from fiber_align.alignment import array_serial as ser
from fiber_align.alignment.states import TRACKING
from fiber_align.jsonout import json_clean
from fiber_align.plant import array_optics as ao
from fiber_align.simulation import harness as hs
from fiber_align.simulation.alignment_bench import LoopRig
from fiber_align.simulation.scenarios import MACHINE_SCENARIOS
from fiber_align.simulation.seeds2d import graph_period_s

SCENARIOS = MACHINE_SCENARIOS['array']
METHODS = {'joint': ar.ArrayMachine, 'serial': ser.SerialArray}
GOAL_LOSS_DB = 0.1
#: The chip's roll is drawn in +- this (rad); its pose keeps the actuators this far (m)
#: inside their stroke.
ROLL_MAX_RAD = 12e-3
EDGE_M = 3e-6
#: The rig starts at 0 and moves to the nominal pose: the detectors' averaging forgets the
#: light it may pass on the way before the floor (``floor_samples``) is read at rest (s).
IDLE_S = 0.05
#: The keys of ``fiber-align simulate --scenario array --json`` (the issue's list).
KEYS = ('channels', 'pitch_m', 'mode_radius_m', 'roll_arm_m', 'waveguide_offsets_m',
        'channel_gains', 'true', 'final', 'worst_channel_loss_db', 'time_to_aligned_s',
        'samples', 'baseline')
BASELINE_KEYS = ('final', 'worst_channel_loss_db', 'time_to_aligned_s', 'samples')


class ArrayRig(LoopRig):
    """Three loops ``x``, ``y_left``, ``y_right``, seeds ``seed`` .. ``seed + 2``."""

    def __init__(self, kind='composite', period_s=1e-3, seed=0):
        """Build the three loops (control period ``period_s``, s)."""
        super().__init__(kind, period_s, seed, 3)


class ArrayBench(hs.Bench):
    """The fiber array: three loops and the array's link; the loss is the worst channel's."""

    POSITION = ar.AXES3
    MEASURED = tuple('m' + a for a in ar.AXES3)
    SETPOINT = tuple('r' + a for a in ar.AXES3)
    TARGET = tuple('t' + a for a in ar.AXES3)
    POWERS = ('p_1', 'p_n')
    JOINT = True
    GOAL = dict(loss_db=GOAL_LOSS_DB, time_s=None, samples=None)
    RIG, LINK = ArrayRig, ao.ArrayLink

    @property
    def ALIGN_MAX_S(self):  # noqa: N802 (the harness's name of the limit)
        """Return the longest alignment (s): the search timeout and 1 s to peak."""
        return self.seq.p['search_timeout_s'] + 1.0

    def sense(self, t, pos):
        """Return the outer channels' readings (W) with the actuators at ``pos`` (m)."""
        return self.link.measure(t, pos, self.period_s)

    def truth(self, t, pos):
        """Return the worst channel's power, its power at the best pose (W), that pose (m)."""
        c = self.link.coupling
        p = c.powers_w(t, pos)
        j = int(np.argmin(p))
        best = c.best()
        ref = c.source_power_w * ao.couplings(best, c.chip, c.u_m, c.offsets_m, c.gains,
                                              c.mode_radius_m)[j]
        return p[j], ref, ao.actuators(*best, c.roll_arm_m)

    def loss(self, t, pos):
        """Return the worst channel's loss in dB with the actuators at ``pos`` (m)."""
        return self.link.coupling.loss_at(t, pos)

    def where(self, t):
        """Return nothing: :func:`figures` reports the chip's pose."""
        return {}


def run_seeds(seed):
    """Return the noise seeds of run ``seed``: ``plant`` (three: .. + 2), ``detector``."""
    return dict(plant=3 * int(seed), detector=int(seed) + 1000)


def random_chip(seed, seq=None):
    """Return the chip's pose ``(x0, y0, roll0)`` (m, m, rad) drawn over the stroke."""
    seq = seq or ar.ArrayMachine(period_s=graph_period_s())
    rng = np.random.default_rng([int(seed), 40])
    lo, hi = float(seq.lo[0]) + EDGE_M, float(seq.hi[0]) - EDGE_M
    roll = float(rng.uniform(-ROLL_MAX_RAD, ROLL_MAX_RAD))
    half = abs(ao.actuators(0.0, 0.0, roll, seq.roll_arm_m)[2])
    return float(rng.uniform(lo, hi)), float(rng.uniform(lo + half, hi - half)), roll


def build(seed=0, method='joint', chip=None, rig=None, seq_overrides=None, record=False,
          **optics_overrides):
    """
    Return an :class:`ArrayBench` with the chip at ``chip`` (``(x0, y0, roll0)``; drawn if None).

    :param rig: an :class:`ArrayRig` to reuse (reset with the seed), or a loop kind.
    :param optics_overrides: keys of node ``simulated_array_optics`` of
        ``config/array.yaml`` (the layout: ``layout_seed``, the run seed unless given), of
        the source and detector of ``optics.yaml``, or the layout itself.
    """
    seq = METHODS[method](**dict(dict(period_s=graph_period_s()), **(seq_overrides or {})))
    chip = random_chip(seed, seq) if chip is None else chip
    ov = dict(dict(layout_seed=int(seed)), **optics_overrides)
    ov.update(chip_x_m=float(chip[0]), chip_y_m=float(chip[1]), chip_roll_rad=float(chip[2]))
    seeds = run_seeds(seed)
    return ArrayBench.assemble(seq, rig, (seeds['plant'], seeds['detector']), record, **ov)


def pose_dict(pose):
    """Return a pose ``(x, y, roll)`` as the JSON's ``{x_m, y_m, roll_rad}``."""
    return None if pose is None else dict(zip(('x_m', 'y_m', 'roll_rad'),
                                              (float(v) for v in pose)))


def figures(bench, res):
    """Return what the JSON reports of a run, in SI: the final pose, the worst loss, ..."""
    c = bench.link.coupling
    ok = res['state'] == TRACKING and bench.seq.state == TRACKING
    final = ao.pose(bench.seq.aligned, c.roll_arm_m) if ok else None
    return dict(final=pose_dict(final), time_to_aligned_s=res['time_to_peak_s'],
                samples=res['samples'], peak_samples=res['peak_samples'],
                state=res['state'], fault_reason=res['fault_reason'],
                worst_channel_loss_db=None if final is None else ao.worst_channel_loss_db(
                    final, c.best(), c.chip, c.u_m, c.offsets_m, c.gains, c.mode_radius_m))


def run(name, seed=0, loop='composite', rig=None, record=False, **kw):
    """
    Run scenario ``array``; return a dict of SI figures (the JSON's keys and more).

    Keyword arguments: ``chip`` (``(x0, y0, roll0)``), ``period_s`` (s), keys of the
    optics files (:func:`build`).
    """
    if name not in SCENARIOS:
        raise ValueError('unknown scenario %r (allowed: %s)' % (name, ', '.join(SCENARIOS)))
    period_s = kw.pop('period_s', None)
    if period_s is not None:
        kw['seq_overrides'] = dict(period_s=float(period_s))
    rig = rig or ArrayRig(loop, period_s or graph_period_s(), 3 * seed)
    out = dict(scenario=name, seed=seed, loop=loop, control_rate_hz=1.0 / rig.period_s)
    for method in ('joint', 'serial'):
        b = build(seed, method, rig=rig, record=record and method == 'joint', **kw)
        res = hs.align_bench(b, idle_s=IDLE_S, loss_window_s=0.02)
        fig = figures(b, res)
        if method == 'joint':
            c = b.link.coupling
            out.update(fig, channels=c.n, pitch_m=c.pitch_m, mode_radius_m=c.mode_radius_m,
                       roll_arm_m=c.roll_arm_m, waveguide_offsets_m=c.offsets_m.tolist(),
                       channel_gains=c.gains.tolist(), true=pose_dict(c.chip),
                       best=pose_dict(c.best()), end_state=b.seq.state)
            if record:
                out['trace'] = b.trace()
        else:
            out['baseline'] = fig
    return out


def run_cli(args):
    """Run ``fiber-align simulate --scenario array``; return an exit code (0: TRACKING)."""
    if getattr(args, 'plot', None) or getattr(args, 'csv', None):
        raise ValueError('--plot and --csv do not apply to --scenario array')
    if getattr(args, 'on_result', None) is not None:
        raise ValueError('--catalog does not record --scenario array yet (its figures are '
                         'not the catalogue\'s columns)')
    rate = getattr(args, 'rate', None)
    res = run(args.scenario, seed=int(args.seed or 0),
              loop=args.loop if args.loop in ('composite', 'ideal') else 'composite',
              **({'period_s': 1.0 / float(rate)} if rate else {}))
    if args.json:
        out = {k: res[k] for k in KEYS}
        out['baseline'] = {k: res['baseline'][k] for k in BASELINE_KEYS}
        print(json.dumps(json_clean(out), indent=2, sort_keys=True))
    else:
        print('scenario array, seed %d: chip (%.2f um, %.2f um, %.2f mrad)'
              % (res['seed'], res['true']['x_m'] * 1e6, res['true']['y_m'] * 1e6,
                 res['true']['roll_rad'] * 1e3))
        for label, r in (('joint', res), ('serial', res['baseline'])):
            print('  %-7s %s %s: worst-channel loss %s dB, time to aligned %s ms, samples %s'
                  % (label, r['state'], r['fault_reason'],
                     '-' if r['worst_channel_loss_db'] is None
                     else '%.4f' % r['worst_channel_loss_db'],
                     '-' if r['time_to_aligned_s'] is None
                     else '%.0f' % (r['time_to_aligned_s'] * 1e3), r['samples']))
    sys.stdout.flush()
    return 0 if res['state'] == TRACKING else 1
