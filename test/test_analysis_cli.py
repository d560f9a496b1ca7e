# SPDX-License-Identifier: Apache-2.0
"""``fiber-align analyze``: metrics equal the offline ones, any writer, clear errors."""

import json
import subprocess
import sys

import numpy as np
import pytest

from fiber_align import cli
from fiber_align.analysis import bag as bagio, report as rp
from fiber_align.analysis.cli import analyze_bag
from fiber_align.simulation import simulate

LAB = ('error', 'error_rate', 'kp', 'ki', 'kd', 'output')


@pytest.fixture(scope='module')
def sim():
    """Return a short offline closed-loop step run (fuzzy PID, no noise)."""
    return simulate.run('step', 'fuzzy', duration_s=0.12, noise=False,
                        setup=simulate.load_setup())


def _lockstep_series(res, wall0=1_700_000_000_000_000_000):
    """Return write_bag series of a run as the lockstep graph would record it."""
    n = res.t.size
    stamp = np.round(res.t * 1e9).astype(np.int64)
    wall = wall0 + np.arange(n) * 3_000_000    # wall time, unrelated to the stamps
    err = res.y_true - res.r
    cs = np.column_stack([err, np.zeros(n), res.gains, res.fb])
    return {
        'clock': {'t_ns': wall, 'clock_ns': stamp},
        'displacement': {'t_ns': wall + 10, 'stamp_ns': stamp, 'position': res.y_meas},
        'setpoint': {'t_ns': wall + 20, 'data': res.r},
        'feedforward_voltage': {'t_ns': wall + 30, 'data': res.ff},
        'feedback_voltage': {'t_ns': wall + 30, 'data': res.fb},
        'drive_voltage': {'t_ns': wall + 40_000, 'data': res.v},
        'controller_state': {'t_ns': wall + 30, 'data': cs},
    }


def _same(a, b, rel=1e-9):
    return abs(a - b) <= rel * max(abs(a), abs(b)) or (a == b)


def _write_plain_rosbags(path, series, storage):
    """Write ``series`` message by message with rosbags' own API (another tool)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    ts = bagio.typestore()
    T = ts.types
    Time = T['builtin_interfaces/msg/Time']
    plug = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3

    def tm(ns):
        return Time(sec=int(ns // 10**9), nanosec=int(ns % 10**9))
    with Writer(path, version=9, storage_plugin=plug) as w:
        for key, s in series.items():
            mt = bagio.GRAPH_TOPICS[key]
            c = w.add_connection(('/' if key == 'clock' else '/bench/') + key, mt, typestore=ts)
            for i, t in enumerate(s['t_ns'].tolist()):
                if mt == bagio.FLOAT64:
                    m = T[mt](data=float(s['data'][i]))
                elif mt == bagio.CLOCK:
                    m = T[mt](clock=tm(s['clock_ns'][i]))
                elif mt == bagio.JOINT_STATE:
                    m = T[mt](header=T['std_msgs/msg/Header'](stamp=tm(s['stamp_ns'][i]),
                                                              frame_id=''),
                              name=['bimorph_tip'], position=np.array([s['position'][i]]),
                              velocity=np.zeros(1), effort=np.zeros(0))
                else:
                    dims = [T['std_msgs/msg/MultiArrayDimension'](label=lb, size=1, stride=1)
                            for lb in LAB]
                    lay = T['std_msgs/msg/MultiArrayLayout'](dim=dims, data_offset=0)
                    m = T[mt](layout=lay, data=np.asarray(s['data'][i], float))
                w.write(c, t, ts.serialize_cdr(m, mt))


def test_lockstep_bag_metrics_equal_offline_simulation(tmp_path, sim):
    """Metrics from a lockstep bag of a run equal simulate's metrics to 1e-9 relative."""
    bagio.write_bag(tmp_path / 'ls', _lockstep_series(sim), namespace='rig')
    skip = sim.metrics['tracking_skip_s']   # simulate's tracking window
    params = dict(rp.default_params(), skip_s=skip)
    res, _ = analyze_bag(tmp_path / 'ls', params, (0.0, 100.0))
    assert res['lockstep'] and res['alignment'] == 'order'
    loop = res['metrics']['loop']
    assert len(loop['steps']) == 1
    st = loop['steps'][0]
    for k in ('settling_time_s', 'overshoot_pct', 'rise_time_s'):
        assert _same(st[k], sim.metrics[k]), (k, st[k], sim.metrics[k])
    for k in ('rms_error_m', 'max_error_m'):
        assert _same(loop['tracking'][k], sim.metrics[k]), k
    assert _same(loop['saturation']['v_max_seen_v'], sim.metrics['max_voltage_v'])
    # the period comes from the stamps (sim time), not from the wall-clock bag times
    assert _same(res['metrics']['timing']['period_s']['mean'], 1.0 / sim.rate_hz, 1e-6)
    lat = res['metrics']['timing']['sensor_to_command_latency_s']
    assert _same(lat['p50'], 39_990e-9)
    assert res['metrics']['gains']['kp']['final'] == sim.gains[-1, 0]


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_bag_from_another_tool_is_analysed_the_same(tmp_path, sim, storage):
    """A bag written message by message with rosbags gives the same metrics as write_bag's."""
    series = _lockstep_series(sim)
    bagio.write_bag(tmp_path / 'ref', series, storage='mcap')
    _write_plain_rosbags(tmp_path / 'other', series, storage)
    a, _ = analyze_bag(tmp_path / 'ref', None, (0.0, 100.0))
    b, _ = analyze_bag(tmp_path / 'other', None, (0.0, 100.0))
    assert b['notes'] == [] and b['lockstep']
    assert json.dumps(a['metrics'], sort_keys=True) == json.dumps(b['metrics'], sort_keys=True)


def test_missing_topic_is_named_and_rest_analysed(tmp_path, sim, capsys):
    """Without setpoint, the note names it and the drive and timing are still analysed."""
    series = _lockstep_series(sim)
    del series['setpoint']
    bagio.write_bag(tmp_path / 'm', series)
    code = cli.main(['analyze', str(tmp_path / 'm'), '--json'])
    out = capsys.readouterr()
    assert code == 0
    res = json.loads(out.out)
    assert any('no setpoint topic' in n for n in res['notes'])
    assert any(n.startswith('analysed anyway:') and 'timing' in n for n in res['notes'])
    assert 'no setpoint topic' in out.err
    assert res['metrics']['timing']['period_s']['n'] == sim.t.size - 1
    # drive + displacement without setpoint: the hysteresis loop is measured
    assert 'max_loop_width_m' in res['metrics']['hysteresis']


@pytest.mark.ros  # starts a process
def test_corrupt_and_foreign_bags_exit_2_without_traceback(tmp_path):
    """A truncated bag and a bag without graph topics fail with one line and exit 2."""
    n = 20000
    bagio.write_bag(tmp_path / 't', {'setpoint': {'t_ns': np.arange(n),
                                                  'data': np.zeros(n)}})
    f = tmp_path / 't' / 't.mcap'
    f.write_bytes(f.read_bytes()[:-5000])
    p = subprocess.run([sys.executable, '-m', 'fiber_align.cli', 'analyze', str(tmp_path / 't')],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2
    assert 'Traceback' not in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert 'cannot read bag' in p.stderr
    from rosbags.rosbag2 import Writer
    with Writer(tmp_path / 'f', version=9) as w:
        w.add_connection('/chatter', 'std_msgs/msg/String', typestore=bagio.typestore())
    code = cli.main(['analyze', str(tmp_path / 'f')])
    assert code == 2


@pytest.mark.ros  # starts a process
def test_plots_and_reports(tmp_path, sim, capsys):
    """--plots writes the figures, --report a Markdown or HTML page that shows them."""
    series = _lockstep_series(sim)
    series['optical_power'] = {'t_ns': series['setpoint']['t_ns'],
                               'data': 1e-3 * np.exp(-((sim.y_true - 82e-6) / 5e-6) ** 2)}
    series['alignment_state'] = {'t_ns': series['setpoint']['t_ns'][[0, 50]],
                                 'data': ['search', 'locked']}
    bagio.write_bag(tmp_path / 'p', series)
    assert cli.main(['analyze', str(tmp_path / 'p'), '--plots', str(tmp_path / 'fig'),
                     '--report', str(tmp_path / 'r.md')]) == 0
    names = {p.name for p in (tmp_path / 'fig').glob('*.png')}
    assert names == {'time.png', 'error.png', 'loop.png', 'gains.png', 'optical_power.png'}
    assert 'report: ' in capsys.readouterr().out
    md = (tmp_path / 'r.md').read_text()
    assert '| tracking | RMS error |' in md and '](fig/time.png)' in md
    assert cli.main(['analyze', str(tmp_path / 'p'), '--report', str(tmp_path / 'r.html'),
                     '--json']) == 0
    res = json.loads(capsys.readouterr().out)
    assert res['report'] == str(tmp_path / 'r.html') and len(res['figures']) == 5
    html = (tmp_path / 'r.html').read_text()
    assert '<img src="r_figures/optical_power.png"' in html and '<table' in html
    r2, _ = analyze_bag(tmp_path / 'p')
    op = r2['metrics']['optical']
    first_lit = int(np.argmax(series['optical_power']['data'] >= 1e-6))
    assert op['time_to_first_light_s'] == pytest.approx(sim.t[first_lit], abs=1e-12)
    assert [e['state'] for e in r2['metrics']['alignment_states']] == ['search', 'locked']


def test_real_time_alignment_assigns_messages_to_their_period():
    """In a real-time bag a message belongs to the period in which it was received."""
    disp = np.array([0, 100, 200, 300], np.int64)
    stream = np.array([10, 20, 150, 320], np.int64)   # two in period 0, none in period 2
    idx = rp.align_index(disp, stream)
    assert idx.tolist() == [1, 2, 2, 3]
    vals = rp.align_values(4, np.array([1.0, 2.0, 3.0, 4.0]), rp.align_index(disp[:], stream))
    assert vals.tolist() == [2.0, 3.0, 3.0, 4.0]
    assert np.isnan(rp.align_values(2, np.array([5.0]), np.array([-1, 0])))[0]
