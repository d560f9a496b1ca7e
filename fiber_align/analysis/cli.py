# SPDX-License-Identifier: Apache-2.0
"""``fiber-align analyze BAG``: metrics, figures and a report from a recorded run."""

import math
from pathlib import Path
import sys

import numpy as np

from fiber_align.analysis import array_run, bag as bagio, plots, report as rp
from fiber_align.analysis import run_kind as rk
from fiber_align.config import ConfigError, load_params
from fiber_align.simulation.metrics import loop_metrics, saturation_metrics, step_settings

NEEDS = {
    'displacement': 'the time base and every loop, step, tracking, timing and hysteresis metric',
    'setpoint': 'step and tracking metrics and the error plot',
    'drive_voltage': 'saturation, latency and the voltage-displacement loop',
}
#: what an alignment run needs beyond :data:`NEEDS`
ALIGN_NEEDS = {
    'optical_power': 'the alignment figures (first light, losses, switch cycles)',
}


def register(subparsers):
    """Add the ``analyze`` sub-command to ``subparsers``."""
    p = subparsers.add_parser(
        'analyze', help='analyse a recorded bag (metrics, plots, report)',
        description='Analyse a rosbag2 bag (mcap or sqlite3) of the fiber_align graph: step, '
                    'tracking, saturation, timing, alignment and hysteresis metrics; figures '
                    'and a Markdown/HTML report. Defaults: config/recorder.yaml, node analyze.')
    p.add_argument('bag', help='bag directory (or .mcap / .db3 file)')
    p.add_argument('--json', action='store_true', help='print the metrics as JSON (SI units)')
    p.add_argument('--plots', metavar='DIR', help='write PNG figures into DIR')
    p.add_argument('--report', metavar='FILE',
                   help='write a report: .md (Markdown) or .html; figures go to --plots DIR '
                        'or FILE_figures/')
    p.add_argument('--skip', type=float, default=None, metavar='S',
                   help='seconds left out at the start of the tracking metrics')
    p.add_argument('--v-min', type=float, default=None, help='lower drive limit (V)')
    p.add_argument('--v-max', type=float, default=None, help='upper drive limit (V)')
    # checked by fiber-align before run (fiber_align.tools.paths)
    p.set_defaults(func=run, paths={'BAG': 'in-any', '--plots': 'out-dir',
                                    '--report': 'out-file'})


def run(args):
    """Run ``analyze``; return the exit code."""
    params = rp.default_params()
    if args.skip is not None:
        params['skip_s'] = args.skip
    if args.skip is not None and (not math.isfinite(args.skip) or args.skip < 0):
        raise ValueError('--skip must be a finite number of seconds >= 0')
    v_limits = _v_limits(args, params)
    want_arrays = bool(args.plots or args.report)
    res, data = analyze_bag(args.bag, params, v_limits, keep_arrays=want_arrays)
    figs = []
    if want_arrays:
        if args.plots:
            fig_dir = Path(args.plots)
        else:
            rpath = Path(args.report)
            fig_dir = rpath.parent / (rpath.stem + '_figures')
        figs = plots.make_figures(fig_dir, data, int(params.get('plot_points', 4000)))
        res['figures'] = [str(f) for _, f in figs]
    if args.report:
        rp.write_report(args.report, res, figs)
        res['report'] = str(args.report)
    if args.json:
        print(rp.to_json(res))
    else:
        print(rp.to_text(res))
        for f in res.get('figures', []):
            print('figure: %s' % f)
        if args.report:
            print('report: %s' % args.report)
    for note in res['notes']:
        print('fiber-align analyze: note: %s' % note, file=sys.stderr)
    return 0


def _v_limits(args, params):
    """
    Return (v_min, v_max) in V from the command line, else the plant config.

    :raises ConfigError: the plant config (``plant_config`` of the analyze settings) is
        missing or lacks ``v_min`` / ``v_max`` (named in the message).
    """
    lo, hi = args.v_min, args.v_max
    if lo is None or hi is None:
        name = params['plant_config']
        plant = load_params(name, 'simulated_actuator')
        try:
            lo = float(plant['v_min']) if lo is None else lo
            hi = float(plant['v_max']) if hi is None else hi
        except KeyError as exc:
            raise ConfigError('%s: node simulated_actuator lacks %s' % (name, exc)) from None
    if not hi > lo:
        raise ValueError('--v-max (%g V) must be above --v-min (%g V)' % (hi, lo))
    return (lo, hi)


def _labels(labels, width):
    labels = list(labels)
    if len(labels) == 1 and ',' in labels[0]:
        labels = [x.strip() for x in labels[0].split(',')]
    if len(labels) != width:
        labels = list(bagio.CONTROLLER_LABELS[:width])
    return labels


def analyze_bag(path, params=None, v_limits=None, keep_arrays=False):
    """
    Analyse the bag at ``path``; return (result dict, arrays for the figures).

    The result holds ``bag``, ``lockstep``, ``alignment``, ``kind`` (``alignment``,
    ``tracking`` or ``open-loop``, see :mod:`fiber_align.analysis.run_kind`), ``topics``
    (found streams), ``notes`` (what is missing and what was analysed anyway) and
    ``metrics`` (SI units). An alignment run gets ``metrics.align`` and no step or
    tracking metrics (the setpoint is the sequencer's search).

    :raises fiber_align.analysis.bag.BagError: unreadable, truncated or corrupt bag, or
        a bag with none of the graph's topics.
    """
    params = dict(rp.default_params() if params is None else params)
    res = {'bag': str(path), 'notes': [], 'metrics': {}}
    data = {}
    with bagio.BagReader(path) as bag:
        lock = bag.is_lockstep()
        res['lockstep'] = lock
        res['topics'] = {k: {'topic': c.topic, 'type': c.msgtype, 'messages': int(c.msgcount)}
                         for k, c in sorted(bag.topics.items())}
        if not bag.topics:
            raise bagio.BagError('bag %s holds none of the graph topics (%s); it has: %s'
                                 % (path, ', '.join(bagio.GRAPH_TOPICS),
                                    ', '.join(sorted(bag.all_topics)) or 'no topics'))
        states = bag.read('alignment_state')
        if states is not None and len(states) == 0:
            states = None
        statuses = rk.parse_states(states.fields.get('msgs', [])) if states else []
        has_sp = 'setpoint' in bag.topics and bool(bag.topics['setpoint'].msgcount)
        res['kind'] = data['kind'] = rk.run_kind(statuses, has_sp)
        needs = dict(NEEDS, **(ALIGN_NEEDS if res['kind'] == rk.ALIGNMENT else {}))
        missing = [k for k in needs if k not in bag.topics or not bag.topics[k].msgcount]
        for k in missing:
            res['notes'].append('bag has no %s topic, needed for %s' % (k, needs[k]))
        run = {'kind': res['kind'], 'states': states, 'statuses': statuses}
        disp = bag.read('displacement', keep=('stamp_ns', 'position'))
        if disp is not None and len(disp) == 0:
            disp = None
        if disp is not None:
            _analyze_loop(bag, disp, lock, params, v_limits, res, data, keep_arrays, run)
        else:
            res['alignment'] = 'none (no time base)'
            _analyze_without_base(bag, params, res, data, keep_arrays, run)
        _analyze_extras(bag, disp, lock, params, res, data, keep_arrays, states)
        _analyze_array(bag, disp, res, data)
    analysed = sorted(k for k, v in res['metrics'].items() if v)
    if missing:
        res['notes'].append('analysed anyway: %s' % (', '.join(analysed) or 'nothing'))
    return res, data


def _align_run(run, t, p, recv_ns, stamp_ns, params, res):
    """Add ``metrics.align`` of an alignment run on a time base (s) with its power (W)."""
    if run['kind'] != rk.ALIGNMENT or p is None:
        return
    idx = rk.state_indices(run['statuses'], run['states'].t_ns, recv_ns, stamp_ns)
    res['metrics']['align'] = rk.alignment_metrics(
        t, p, list(zip(idx, run['statuses'])), float(params.get('light_threshold_w', 1e-6)))


def _analyze_loop(bag, disp, lock, params, v_limits, res, data, keep, run):
    """Compute loop, timing and hysteresis metrics on the displacement time base."""
    stamp = disp.fields['stamp_ns']
    t = (stamp - stamp[0]) / 1e9
    y = disp.fields['position']
    n = t.shape[0]
    res['alignment'] = 'order' if lock else 'receive-time'
    al = {'t': t, 'y': y, 'stamp_ns': stamp, 'recv_ns': disp.t_ns}
    drive_t_ns = None
    for key in rp.FLOAT_STREAMS:
        s = bag.read(key)
        if s is None or len(s) == 0:
            continue
        if lock and len(s) != n:
            res['notes'].append('%s has %d messages for %d displacement samples (lockstep '
                                'pairs them by order)' % (key, len(s), n))
        idx = None if lock else rp.align_index(disp.t_ns, s.t_ns)
        al[key] = rp.align_values(n, s.fields['data'], idx)
        if key == 'drive_voltage':
            drive_t_ns = s.t_ns
        del s
    r = al.get('setpoint')
    v = al.get('drive_voltage')
    loop = {}
    if r is not None and run['kind'] == rk.ALIGNMENT:
        # the setpoint is the sequencer's search: its jumps are no steps to score
        loop = {'samples': int(n)}
        if v is not None:
            loop['saturation'] = saturation_metrics(t, v, v_limits)
    elif r is not None:
        loop = loop_metrics(t, r, y, v, v_limits, skip_s=float(params.get('skip_s', 0.0)),
                            **step_settings(params))
    elif v is not None:
        loop = {'samples': int(n), 'saturation': saturation_metrics(t, v, v_limits)}
    res['metrics']['loop'] = loop
    res['metrics']['timing'] = rp.timing_metrics(al, drive_t_ns, lock)
    if v is not None and r is None:
        res['metrics']['hysteresis'] = rp.hysteresis_metrics(v, y)
    if 'optical_power' in al:
        res['metrics']['optical'] = rp.optical_metrics(
            t, al['optical_power'], float(params.get('light_threshold_w', 1e-6)))
        _align_run(run, t, al['optical_power'], disp.t_ns, stamp, params, res)
        if keep:
            data['power_t'], data['power'] = t, al['optical_power']
    if keep:
        data.update({k: al[k] for k in ('t', 'y') + rp.FLOAT_STREAMS if k in al})


def _analyze_without_base(bag, params, res, data, keep, run):
    """
    Analyse what needs no displacement: drive range and optical power on receive time.

    An alignment run (e.g. the sensorless hardware graph) is analysed on the power
    stream's receive times.
    """
    t0 = None
    for key in ('drive_voltage', 'optical_power'):
        s = bag.read(key)
        if s is None or len(s) == 0:
            continue
        t0 = s.t_ns[0] if t0 is None else min(t0, s.t_ns[0])
        tt = (s.t_ns - t0) / 1e9
        if key == 'drive_voltage':
            res['metrics']['loop'] = {'saturation': saturation_metrics(
                tt, s.fields['data'], None)}
        else:
            res['metrics']['optical'] = rp.optical_metrics(
                tt, s.fields['data'], float(params.get('light_threshold_w', 1e-6)))
            _align_run(run, tt, s.fields['data'], s.t_ns, None, params, res)
            if keep:
                data['power_t'], data['power'] = tt, s.fields['data']


def _time_of(disp, lock, t_ns, n_fallback_t0=None):
    """Map receive times (ns) to the run's time base (s)."""
    if disp is None:
        return (t_ns - (t_ns[0] if n_fallback_t0 is None else n_fallback_t0)) / 1e9
    stamp = disp.fields['stamp_ns']
    t = (stamp - stamp[0]) / 1e9
    i = np.clip(np.searchsorted(disp.t_ns, t_ns, side='right') - 1, 0, t.size - 1)
    return t[i]


def _analyze_array(bag, disp, res, data):
    """Add ``metrics.array`` from the last ``array_model`` message (the array's model)."""
    model = bag.read('array_model')
    if model is None or not len(model) or model.fields.get('data') is None:
        return
    try:
        t0 = 0.0 if disp is None else float(disp.fields['stamp_ns'][0]) / 1e9
        res['metrics']['array'] = data['array'] = array_run.array_metrics(
            model.labels, model.fields['data'][-1], t0, res['metrics'].get('align'))
    except ValueError as exc:
        res['notes'].append('array_model not read: %s' % exc)


def _analyze_extras(bag, disp, lock, params, res, data, keep, s):
    """Add gains, alignment states and diagnostics summaries."""
    c = bag.topics.get('controller_state')
    if c is not None and c.msgcount:
        stride = max(1, -(-int(c.msgcount) // int(params.get('plot_points', 4000))))
        cs = bag.read('controller_state', stride=stride)
        arr = cs.fields.get('data')
        if arr is not None and arr.ndim == 2 and arr.shape[0]:
            labels = _labels(cs.labels, arr.shape[1])
            if lock and disp is not None:
                stamp = disp.fields['stamp_ns']
                t = (stamp - stamp[0]) / 1e9
                k = np.minimum(np.arange(arr.shape[0]) * stride, t.size - 1)
                gt = t[k]
            else:
                gt = _time_of(disp, lock, cs.t_ns)
            gains = {g: arr[:, labels.index(g)] for g in ('kp', 'ki', 'kd') if g in labels}
            res['metrics']['gains'] = {
                g: {'min': float(np.nanmin(x)), 'max': float(np.nanmax(x)),
                    'final': float(x[-1])} for g, x in gains.items()}
            res['metrics']['gains']['sampled_every'] = stride
            if keep and gains:
                data['gains'], data['gains_t'] = gains, gt
    if s is not None and len(s):
        tt = _time_of(disp, lock, s.t_ns)
        ev, last = [], None
        for ti, m in zip(tt.tolist(), s.fields.get('msgs', [])):
            if m.data != last:
                ev.append({'t_s': ti, 'state': m.data})
                last = m.data
        res['metrics']['alignment_states'] = ev[:1000]
    d = bag.read('diagnostics')
    if d is not None and len(d):
        levels = {}
        for m in d.fields.get('msgs', []):
            for st in m.status:
                lv = int.from_bytes(st.level, 'little') if isinstance(st.level, bytes) \
                    else int(st.level)
                key = '%s level %d' % (st.name, lv)
                levels[key] = levels.get(key, 0) + 1
        res['metrics']['diagnostics'] = {'messages': len(d), 'status_counts': levels}
