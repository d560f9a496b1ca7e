# SPDX-License-Identifier: Apache-2.0
"""
Offline station scenarios: the station sequencer (and its serial baseline) on four axes.

The rig is four independent closed loops (:class:`StationRig`: input x-y and output x-y,
each the control core's plant, composite controller, driver and sensor noise, its own seed),
stepped at the control rate in the order of docs/CONTRACTS.md. One period ``k``: the four
measured displacements and the output detector's reading ``P_k`` (W, of the true positions
at ``t_k``) go to ``seq.update(t_k, positions, P_k)``, whose four setpoints drive the loops
for one period (the steps of :mod:`fiber_align.simulation.harness`; this module holds the
station's data, :class:`StationBench`, and its own step, :func:`cure_bench`).

``station``
    Both facets at random offsets from the nominal positions (2-20 um on every axis, random
    signs, drawn from the seed); from IDLE, ``align``. Metrics as ``align2d``:
    ``time_to_first_light_s``, ``time_to_peak_s`` (command to TRACKING), ``final_loss_db``
    (true loss against the true joint peak, mean over the first ``loss_window_s`` of
    TRACKING, dithers included), ``peak_samples`` (readings in PEAKING), ``search_samples``,
    ``samples``; the serial baseline's under ``baseline``, on the same facets and seeds;
    ``samples_ratio`` = concurrent / serial peak samples.
``cure``
    Align (the station's method), then the adhesive pulls each fiber 0.5-2 um in a random
    direction over 10-60 s (drawn from the seed); tracking on, and, from a copy of the same
    aligned rig, tracking off (setpoints held). ``max_loss_db`` (largest true loss from the
    cure's start), ``final_loss_db`` (mean over the last ``final_window_s``),
    ``untracked_max_loss_db``, ``untracked_final_loss_db``; the alignment's own final loss
    is ``align_final_loss_db``.
"""

import copy
import math

import numpy as np

from fiber_align.alignment import station as st
from fiber_align.alignment import station_serial as ser
from fiber_align.alignment.states import TRACKING
from fiber_align.plant import station_optics as so
from fiber_align.simulation import harness as hs
from fiber_align.simulation.alignment_bench import LoopRig
from fiber_align.simulation.scenarios import MACHINE_SCENARIOS
from fiber_align.simulation.seeds2d import graph_period_s

SCENARIOS = MACHINE_SCENARIOS['station']
METHODS = {'concurrent': st.Station, 'serial': ser.SerialStation}
GOAL_LOSS_DB = 0.05
#: The four axes in the order of the sequencer's positions and setpoints (the graph's
#: ``in/x`` .. ``out/y`` namespaces).
AXIS_KEYS = ('x_in', 'y_in', 'x_out', 'y_out')


class StationRig(LoopRig):
    """Input and output x-y rigs: four loops ``in/x`` .. ``out/y``, seeds ``seed`` .. ``+ 3``."""

    def __init__(self, kind='composite', period_s=1e-3, seed=0):
        """Build the four loops (control period ``period_s``, s)."""
        super().__init__(kind, period_s, seed, 4)


class Hold:
    """Tracking off: the setpoints held at the aligned point (the ``update`` API)."""

    state = 'HOLD'

    def __init__(self, point):
        """Hold ``point`` (4 values, m)."""
        self.point = tuple(float(v) for v in point)

    def update(self, t_s, positions_m, power_w, driver_active=None):
        """Return the held setpoints (m)."""
        return self.point


class StationBench(hs.Bench):
    """The coupled station: four loops and the chip's link (:mod:`.plant.station_optics`)."""

    POSITION = AXIS_KEYS
    MEASURED = tuple('m' + a for a in AXIS_KEYS)
    SETPOINT = tuple('r' + a for a in AXIS_KEYS)
    TARGET = tuple('t' + a for a in AXIS_KEYS)
    JOINT = True
    GOAL = dict(loss_db=GOAL_LOSS_DB, time_s=None, samples=None)
    WHERE = 'facets_m'
    RIG, LINK = StationRig, so.StationLink

    @property
    def ALIGN_MAX_S(self):  # noqa: N802 (the harness's name of the limit)
        """Return the longest alignment (s): the search timeout and 2 s to peak."""
        return self.seq.p['search_timeout_s'] + 2.0


def run_seeds(seed):
    """Return the noise seeds of run ``seed``: ``plant`` (four: .. + 3), ``detector``."""
    return dict(plant=4 * int(seed), detector=int(seed) + 1000)


def random_facets(seed, seq=None, lo_m=2e-6, hi_m=20e-6):
    """Return the four facet coordinates (m): nominal + 2-20 um, random signs, per axis."""
    seq = seq or st.Station(period_s=graph_period_s())
    rng = np.random.default_rng([seed, 24])
    off = rng.uniform(lo_m, hi_m, 4) * rng.choice((-1.0, 1.0), 4)
    return tuple(float(v) for v in seq.park + off)


def random_cure(seed):
    """Return the cure overrides of run ``seed``: per fiber 0.5-2 um, any angle, 10-60 s."""
    rng = np.random.default_rng([seed, 25])
    out = {}
    for s in so.SIDES:
        out['cure_%s_amplitude_m' % s] = float(rng.uniform(0.5e-6, 2e-6))
        out['cure_%s_angle_rad' % s] = float(rng.uniform(0.0, 2.0 * math.pi))
        out['cure_%s_duration_s' % s] = float(rng.uniform(10.0, 60.0))
    return out


def build(seed=0, method='concurrent', facets=None, rig=None, seq_overrides=None,
          record=False, **optics_overrides):
    """
    Return a :class:`StationBench` with the facets at ``facets`` (m; random if None).

    :param rig: a :class:`StationRig` to reuse (reset with the seed), or a loop kind.
    :param optics_overrides: keys of ``config/station.yaml`` (node
        ``simulated_station_optics``) or of the source and detector of ``optics.yaml``.
    """
    seq = METHODS[method](**dict(dict(period_s=graph_period_s()), **(seq_overrides or {})))
    facets = random_facets(seed, seq) if facets is None else facets
    ov = dict(optics_overrides)
    ov.update(('facet_%s_%s_m' % (s, a), float(v))
              for (s, a), v in zip([(s, a) for s in so.SIDES for a in 'xy'], facets))
    seeds = run_seeds(seed)
    return StationBench.assemble(seq, rig, (seeds['plant'], seeds['detector']), record, **ov)


def align_bench(bench, idle_s=0.02, loss_window_s=0.02):
    """Idle, ``align``, run to TRACKING or FAULT, the loss window; return metrics (SI)."""
    out = hs.align_bench(bench, idle_s, None, loss_window_s)
    out['aligned_offset_m'] = None
    if out['state'] == TRACKING:
        pk = np.asarray(bench.link.coupling.peak(bench.t))
        out['aligned_offset_m'] = float(np.linalg.norm(np.asarray(bench.seq.aligned) - pk))
    return out


def cure_bench(bench, cure, settle_s=0.2, tail_s=2.0, final_window_s=1.0):
    """
    From TRACKING, start the cure ``settle_s`` later; track on, and off from a copy.

    :param cure: the ``cure_*`` keys of :func:`random_cure` (m, rad, s).
    :returns: dict of the two runs' loss figures (dB) and the cure (SI).
    """
    t0 = bench.t + settle_s
    cures = tuple(so.CureDrift(cure['cure_%s_amplitude_m' % s], cure['cure_%s_angle_rad' % s],
                               cure['cure_%s_duration_s' % s], t0) for s in so.SIDES)
    bench.link.coupling.cures = cures
    t_end = t0 + max(c.duration_s for c in cures) + tail_s
    off = copy.deepcopy(bench)
    off.seq = Hold(bench.seq.aligned)
    out = dict(cure_start_s=t0, cure_end_s=t_end - tail_s, **cure)
    for label, b in (('', bench), ('untracked_', off)):
        losses = []
        while b.t < t_end - 1e-12:
            b.step()
            if b.last[0] >= t0:
                losses.append(b.true_loss())
        arr = np.asarray(losses)
        n = max(1, int(round(final_window_s / b.period_s)))
        out[label + 'max_loss_db'] = float(arr.max())
        out[label + 'final_loss_db'] = float(arr[-n:].mean())
    out['end_state'] = bench.seq.state
    out['end_fault_reason'] = bench.seq.fault_reason
    return out


def run(name, seed=0, loop='composite', rig=None, record=False, **kw):
    """
    Run scenario ``name`` (``station`` or ``cure``); return a dict of SI metrics.

    ``station``: the concurrent method's metrics, the serial baseline's under ``baseline``,
    ``samples_ratio`` (concurrent / serial peak samples) and ``time_ratio``. ``cure``: the
    alignment's metrics plus :func:`cure_bench`'s, the serial alignment under ``baseline``
    is left out (the cure compares tracking on and off). Keyword arguments: ``facets``
    (four, m), ``period_s`` (s), ``cure_duration_s`` (s: both fibers' pull over this time
    instead of the drawn ones), keys of the optics files.
    """
    if name not in SCENARIOS:
        raise ValueError('unknown scenario %r (allowed: %s)' % (name, ', '.join(SCENARIOS)))
    period_s = kw.pop('period_s', None)
    cure_duration_s = kw.pop('cure_duration_s', None)
    if period_s is not None:
        kw['seq_overrides'] = dict(period_s=float(period_s))
    rig = rig or StationRig(loop, period_s or graph_period_s(), 4 * seed)
    b = build(seed, 'concurrent', rig=rig, record=record, **kw)
    out = align_bench(b)
    out.update(scenario=name, seed=seed, loop=loop, control_rate_hz=1.0 / rig.period_s)
    if name == 'cure':
        out['align_final_loss_db'] = out.pop('final_loss_db')
        if b.seq.state == TRACKING:
            cure = random_cure(seed)
            if cure_duration_s is not None:
                for side in so.SIDES:
                    cure['cure_%s_duration_s' % side] = float(cure_duration_s)
            out.update(cure_bench(b, cure))
        else:
            out.update(max_loss_db=None, final_loss_db=None, untracked_max_loss_db=None,
                       untracked_final_loss_db=None, end_state=b.seq.state,
                       end_fault_reason=b.seq.fault_reason)
        out['simulated_s'] = b.t
        return out
    hs.end(out, b)
    base_bench = build(seed, 'serial', rig=rig, **kw)
    base = align_bench(base_bench)
    base.update(end_state=base_bench.seq.state, end_fault_reason=base_bench.seq.fault_reason)
    out['baseline'] = base
    for key, k in (('samples_ratio', 'peak_samples'), ('time_ratio', 'time_to_peak_s')):
        out[key] = hs.ratio(out.get(k), base.get(k))
    return out


def run_cli(args):
    """Run ``fiber-align simulate --scenario station|cure``; return an exit code."""
    return hs.run_cli(args, run)
