# SPDX-License-Identifier: Apache-2.0
"""
Offline two-axis scenarios: the 2-D sequencer (and its hill-climb baseline) on a rig.

The rig is two independent closed loops (:class:`Rig2D`: x and y, each its own plant,
composite controller, driver, sensor noise and seed, from the control core's config files),
stepped at the control rate in the order of docs/CONTRACTS.md. One period ``k``: both loops'
measurements ``(x_k, y_k)`` (m) and the detector reading ``P_k`` (W, of the true tip position
at ``t_k``) go to ``seq.update(t_k, x_k, y_k, P_k)``, whose setpoints drive the two loops for
one period (the steps of :mod:`fiber_align.simulation.harness`; this module holds the
rig's data: :class:`Bench2D`). ``run(name, seed)`` runs scenario ``name`` with the
sequencer and then, on the same target and noise seeds, with the hill climb, and returns SI
metrics (the baseline's under ``baseline``):

``align2d``
    From IDLE, ``align`` with the target at a random point of the reachable square:
    ``time_to_first_light_s``, ``time_to_peak_s`` (command to TRACKING), ``final_loss_db``
    (true loss against the true maximum, mean over the first ``loss_window_s`` of TRACKING,
    dither included), ``peak_samples`` (readings in PEAKING, as the 1-D ``align``),
    ``search_samples``, ``samples`` (all readings from the command to TRACKING).
``track2d``
    Align, then track a target drifting at ``drift_m_per_s`` in a random direction and
    vibrating (``vibration_m`` at ``vibration_hz``, random direction) for ``duration_s``;
    loss statistics over the run after ``skip_s``.
``switch2d``
    Align, then ``cycles`` switch off/on cycles; the loss at the end of each on period.
"""

import math

import numpy as np

from fiber_align.alignment import hillclimb2d as hc
from fiber_align.alignment import sequencer2d as s2d
from fiber_align.plant import optics2d as o2
from fiber_align.simulation import harness as hs
from fiber_align.simulation.alignment_bench import LoopRig
from fiber_align.simulation.harness import align_bench  # noqa: F401 (the API)
from fiber_align.simulation.scenarios import MACHINE_SCENARIOS
from fiber_align.simulation.seeds2d import graph_period_s, random_target, run_seeds  # noqa: F401

SCENARIOS = MACHINE_SCENARIOS['rig']
METHODS = ('sequencer', 'hillclimb')
GOAL = dict(loss_db=0.05, time_s=1.0, samples=150)   # issue 14, align from IDLE


class Rig2D(LoopRig):
    """The x-y rig: two loops (``composite`` or ``ideal``), noise seeds ``seed``, ``seed + 1``."""

    def __init__(self, kind='composite', period_s=1e-3, seed=0):
        """Build both loops (control period ``period_s``, s)."""
        super().__init__(kind, period_s, seed, 2)


class Bench2D(hs.Bench):
    """The x-y rig: two loops, the 2-D link of :mod:`~fiber_align.plant.optics2d`."""

    POSITION, MEASURED, SETPOINT, TARGET = ('x', 'y'), ('mx', 'my'), ('rx', 'ry'), ('tx', 'ty')
    GOAL = GOAL
    WHERE = ('target_x_m', 'target_y_m')
    RIG, LINK = Rig2D, o2.OpticalLink2D


def make_sequencer(method, **overrides):
    """Return a fresh ``sequencer`` (:class:`Sequencer2D`) or ``hillclimb`` baseline."""
    overrides.setdefault('period_s', graph_period_s())
    if method == 'sequencer':
        return s2d.Sequencer2D(**overrides)
    if method == 'hillclimb':
        return hc.HillClimb2D(**overrides)
    raise ValueError('unknown method %r (allowed: %s)' % (method, ', '.join(METHODS)))


def build(seed=0, method='sequencer', target=None, rig=None, record=False, seq_overrides=None,
          **optics_overrides):
    """
    Return a :class:`Bench2D` with the target at ``target`` (m; random if None).

    :param rig: a :class:`Rig2D` to reuse (reset with ``seed``), or a loop kind.
    :param optics_overrides: keys of ``optics.yaml`` and of the ``target`` of
        ``optics2d.yaml`` (e.g. ``fiber_broken=True``, ``drift_x_m_per_s``).
    """
    seq = make_sequencer(method, **(seq_overrides or {}))
    if target is None:
        target = random_target(seed, seq)
    seeds = run_seeds(seed)
    return Bench2D.assemble(seq, rig, (seeds['plant_x'], seeds['detector']), record,
                            **dict(optics_overrides, position_x_m=float(target[0]),
                                   position_y_m=float(target[1])))


def run_method(name, method, seed=0, rig=None, record=False, target=None, **kw):
    """Run scenario ``name`` with one method; return a dict of SI metrics."""
    kw = dict(kw)
    cycles = int(kw.pop('cycles', 5))
    duration_s = float(kw.pop('duration_s', 60.0))
    drift = float(kw.pop('drift_m_per_s', 1e-6))
    vib = float(kw.pop('vibration_m', 0.2e-6))
    vib_hz = float(kw.pop('vibration_hz', 30.0))
    if name == 'track2d':
        rng = np.random.default_rng([seed, 60])
        ang, vang = rng.uniform(0.0, 2.0 * math.pi, 2)
        seq = s2d.Sequencer2D(period_s=graph_period_s())
        # start so that the whole drift stays inside the square, centred on its middle
        mid = 0.5 * (seq.lo + seq.hi)
        u = np.array([math.cos(ang), math.sin(ang)])
        if target is None:
            target = tuple(mid - u * drift * 0.5 * (duration_s + 0.5))
        kw.update(drift_x_m_per_s=drift * u[0], drift_y_m_per_s=drift * u[1],
                  vibration_amplitude_m=vib, vibration_frequency_hz=vib_hz,
                  vibration_angle_rad=vang)
    bench = build(seed=seed, method=method, target=target, rig=rig, record=record, **kw)
    out = hs.align_bench(bench)
    if name == 'switch2d' and bench.seq.state == s2d.TRACKING:
        bench.run_until(bench.t + 0.1)
        out.update(hs.switch_cycles(bench, cycles=cycles))
    elif name == 'track2d' and bench.seq.state == s2d.TRACKING:
        t_cmd, skip_s = 0.02, 1.0
        out.update(hs.track_bench(bench, duration_s, t_cmd + skip_s))
        out.update(drift_m_per_s=drift, vibration_m=vib, vibration_hz=vib_hz)
    out['method'] = method
    hs.end(out, bench)
    if record:
        out['trace'] = bench.trace()
    return out


def run(name, seed=0, loop='composite', record=False, rig=None, **kw):
    """
    Run scenario ``name`` (align2d, track2d, switch2d) with the sequencer and the baseline.

    Returns the sequencer's metrics with the hill climb's under ``baseline`` and the ratios
    ``samples_ratio`` / ``time_ratio`` (hill climb / sequencer, peak samples and time to
    peak). Keyword arguments: ``target`` ``(x, y)`` (m), ``period_s`` (s; default the
    graph's 1 / ``rate_hz``), ``cycles``, ``duration_s`` (s),
    ``drift_m_per_s`` (m/s), ``vibration_m`` (m), ``vibration_hz`` (Hz), keys of the
    optics files.
    """
    if name not in SCENARIOS:
        raise ValueError('unknown scenario %r (allowed: %s)' % (name, ', '.join(SCENARIOS)))
    period_s = kw.pop('period_s', None)
    if period_s is not None:
        kw['seq_overrides'] = dict(period_s=float(period_s))
    rig = rig or Rig2D(loop, period_s or graph_period_s(), 2 * seed)
    out = run_method(name, 'sequencer', seed, rig, record, **kw)
    base = run_method(name, 'hillclimb', seed, rig, record, **kw)
    out.update(scenario=name, seed=seed, loop=loop, control_rate_hz=1.0 / rig.period_s,
               baseline=base)
    for key, k in (('samples_ratio', 'peak_samples'), ('time_ratio', 'time_to_peak_s')):
        out[key] = hs.ratio(base.get(k), out.get(k))
    return out


def run_cli(args, plot=None):
    """
    Run ``fiber-align simulate --scenario align2d|track2d|switch2d``; return an exit code.

    :param plot: ``plot(res, path)`` for ``--plot`` (the caller's figure; None: no figure).
    """
    return hs.run_cli(args, run, plot, ('cycles', 'duration', 'drift', 'target'))
