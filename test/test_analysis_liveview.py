# SPDX-License-Identifier: Apache-2.0
"""The pure parts of the Foxglove live view (``fiber_align.analysis.liveview``)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fiber_align.analysis import liveview as lv
from fiber_align.analysis import powermap
from fiber_align.analysis.bag.common import typestore

ROOT = Path(__file__).resolve().parents[1]
LAYOUTS = sorted((ROOT / 'layouts').glob('*.json'))


def _msg_reader():
    """Return a reader of ``.msg`` texts from the interpreter's ROS share directory."""
    import sys
    share = Path(sys.prefix) / 'share'

    def read(pkg, name):
        return (share / pkg / 'msg' / (name + '.msg')).read_text(encoding='utf-8')
    if not (share / 'sensor_msgs' / 'msg' / 'JointState.msg').is_file():
        pytest.fail('no sensor_msgs .msg files under %s (the ros extra installs them)' % share)
    return read


def test_schema_text_is_the_definition_then_each_dependency_once_depth_first():
    texts = {('a', 'Top'): 'b/Mid m\na/Leaf[] leaves  # comment b/Ignored\nint8 K=1\n',
             ('b', 'Mid'): 'a/Leaf one\nstring<=5 s\nuint8[3] u\n',
             ('a', 'Leaf'): 'float64 x\n'}
    out = lv.ros2msg_schema('a/msg/Top', lambda p, n: texts[(p, n)])
    sep = '\n' + '=' * 80 + '\n'
    # sorted deps: a/Leaf before b/Mid; b/Mid's a/Leaf is not written twice
    assert out == (texts[('a', 'Top')] + sep + 'MSG: a/Leaf\n' + texts[('a', 'Leaf')]
                   + sep + 'MSG: b/Mid\n' + texts[('b', 'Mid')])
    assert lv.msg_dependencies('a', 'Leaf x\nstring<=3 name\nint32 A = 3\n') == ['a/Leaf']


def test_schema_text_of_the_graph_types_matches_the_mcap_definitions_of_rosbags():
    # rosbags writes the same ros2msg layout into every mcap bag (comments dropped)
    read = _msg_reader()
    ts = typestore()
    for t in ('sensor_msgs/msg/JointState', 'std_msgs/msg/Float64MultiArray',
              'diagnostic_msgs/msg/DiagnosticArray', 'std_msgs/msg/Float64'):
        ours = lv.ros2msg_schema(t, read)
        theirs = ts.generate_msgdef(t, ros_version=2)[0]

        def sections(text):
            return [s.split('\n', 1)[0] for s in text.split('=' * 80 + '\nMSG: ')[1:]]
        assert sorted(sections(ours)) == sorted(sections(theirs)), t


def test_decimator_passes_one_frame_per_period_without_bursts():
    d = lv.Decimator(100.0)
    t = np.arange(0.0, 1.0, 0.001)          # a 1 kHz topic for 1 s
    passed = [x for x in t if d.due(x)]
    assert 99 <= len(passed) <= 101
    gaps = np.diff(passed)
    assert gaps.min() >= 0.0075 - 1e-9 and gaps.mean() == pytest.approx(0.01, rel=0.02)
    # a stall of 0.5 s: one frame, then the phase goes on (no catch-up burst)
    assert d.due(1.5) and not d.due(1.5005) and not d.due(1.505)
    # a timer tick a little early still gets its frame
    assert d.due(1.5095)
    assert '0.01 s' in d.describe() and '100 Hz' in d.describe()
    with pytest.raises(ValueError):
        lv.Decimator(0.0)


def test_cdr_decoders_read_what_rosbags_serialises():
    ts = typestore()
    Time = ts.types['builtin_interfaces/msg/Time']
    Header = ts.types['std_msgs/msg/Header']
    JS = ts.types['sensor_msgs/msg/JointState']
    msg = JS(header=Header(stamp=Time(sec=3, nanosec=250), frame_id='frame'),
             name=['bimorph_tip', 'b'], position=np.array([12.5e-6, -1.0]),
             velocity=np.array([0.1, 0.2]), effort=np.array([], dtype=float))
    data = bytes(ts.serialize_cdr(msg, 'sensor_msgs/msg/JointState'))
    stamp, pos = lv.joint_state(data)
    assert stamp == 3_000_000_250 and pos == (12.5e-6, -1.0)
    f = ts.types['std_msgs/msg/Float64'](data=-2.5e-3)
    assert lv.float64_value(bytes(ts.serialize_cdr(f, 'std_msgs/msg/Float64'))) == -2.5e-3
    s = ts.types['std_msgs/msg/String'](data='{"state": "IDLE"}')
    assert lv.string_value(bytes(ts.serialize_cdr(s, 'std_msgs/msg/String'))) \
        == '{"state": "IDLE"}'
    with pytest.raises(ValueError):
        lv.float64_value(b'garbage')


def test_pairer_pairs_as_the_realtime_sequencer():
    p = powermap.SamplePairer()
    assert p.x(1.0) is None                 # no y, no power yet
    p.y(2.0)
    p.power(1e-6)
    p.power(2e-6)                           # the newest since the previous x counts
    assert p.x(1.5) == (1.5, 2.0, 2e-6)
    assert p.x(1.6) is None                 # no power since


def test_power_map_keeps_the_brightest_reading_per_cell_and_its_grid_says_so():
    m = powermap.PowerMap(0.0, 65e-6, 0.0, 65e-6, 0.5e-6)
    assert (m.nx, m.ny) == (130, 130) and m.peak() is None
    rng = np.random.default_rng(0)
    peak = (31.3e-6, 40.9e-6)
    for x, y in rng.uniform(0.0, 65e-6, size=(20000, 2)):
        m.add(x, y, 1e-3 * math.exp(-((x - peak[0]) ** 2 + (y - peak[1]) ** 2) / 5.2e-6 ** 2))
    assert not m.add(70e-6, 1e-6, 1.0) and not m.add(math.nan, 1e-6, 1.0)
    x, y, p = m.peak()
    assert math.hypot(x - peak[0], y - peak[1]) < 0.75e-6     # within a cell diagonal
    g = json.loads(lv.json_bytes(m.grid(1_000_000_123, 'rig')))
    assert g['timestamp'] == {'sec': 1, 'nsec': 123} and g['column_count'] == 130
    assert g['row_stride'] == 130 * 4 and g['fields'][0]['type'] == powermap.FLOAT32
    gx, gy, v = powermap.grid_peak(g)
    assert (gx, gy) == pytest.approx((x, y)) and v == pytest.approx(lv.dbm(p), abs=1e-4)
    m.reset()
    assert m.peak() is None and m.count == 0


def test_search_map_pairs_by_source_stamp_and_starts_anew_with_a_search():
    from fiber_align.analysis.bag.cdr import encode_float64, encode_joint_state
    m = powermap.SearchMap(0.0, 10e-6, 0.0, 10e-6, 1e-6, 0.5)
    pos = [bytes(r) for r in encode_joint_state([0, 0], [5.5e-6, 2.5e-6])]
    power = bytes(encode_float64([1e-3])[0])
    assert m.due(1.0, 0) is None                        # nothing to show yet
    m.feed([(3, 'x', pos[0]), (1, 'y', pos[1]), (2, 'p', power)])     # y, p, then x
    assert m.map.count == 1
    assert powermap.grid_peak(m.due(2.0, 0))[:2] == pytest.approx((5.5e-6, 2.5e-6))
    assert m.due(2.1, 0) is None and m.due(2.1, 0, resend=True) is not None
    m.on_state('SEARCHING')
    assert m.map.count == 0


def test_dbm_and_alignment_view():
    assert lv.dbm(1e-3) == 0.0 and lv.dbm(1e-6) == pytest.approx(-30.0)
    assert lv.dbm(0.0) == -math.inf and math.isnan(lv.dbm(-1.0))
    assert lv.power_dbm_view(0.0) == {'power_w': 0.0, 'power_dbm': None}
    v = lv.alignment_view('{"state": "TRACKING", "aligned_x_m": 1e-6}')
    assert v['state_index'] == lv.STATES.index('TRACKING') and v['aligned_x_m'] == 1e-6
    assert lv.alignment_view('{"state": "?"}')['state_index'] == -1
    with pytest.raises(ValueError):
        lv.alignment_view('[1]')
    assert json.loads(lv.json_bytes({'a': math.nan, 'b': [math.inf, 1.0]})) \
        == {'a': None, 'b': [None, 1.0]}


def test_layout_topics_reads_every_path_of_a_layout():
    layout = {'configById': {
        'Plot!1': {'paths': [{'value': '/displacement.position[0]'},
                             {'value': '/rig/x/setpoint.data'}]},
        'StateTransitions!2': {'paths': [{'value': '/live_view/alignment.state'}]},
        '3D!3': {'topics': {'/rig/live_view/power_map': {'visible': True}}},
        'Indicator!4': {'path': 'not a topic', 'topicPath': '/drive_held.data'}}}
    assert lv.layout_topics(layout) == {'/displacement', '/rig/x/setpoint',
                                        '/live_view/alignment', '/rig/live_view/power_map',
                                        '/drive_held'}
    with pytest.raises(ValueError):
        lv.path_topic('displacement')


@pytest.mark.parametrize('path', LAYOUTS, ids=[p.name for p in LAYOUTS])
def test_shipped_layouts_are_json_with_panels_that_read_topics(path):
    layout = json.loads(path.read_text(encoding='utf-8'))
    assert layout['configById'] and lv.layout_topics(layout)


def test_layouts_are_shipped():
    assert {p.name for p in LAYOUTS} == {'fiber_align.json', 'fiber_align_rig.json',
                                         'fiber_align_array.json'}


def test_the_array_layout_reads_what_the_array_graph_serves_at_the_model_s_indices():
    """Its topics are the live array graph's; each ``array_model.data[k]`` is the label named."""
    import re
    from fiber_align.config import load_params
    from fiber_align.graph import array as ga
    from fiber_align.graph.live import graph_topics, with_live
    from fiber_align.plant import array_optics as ao
    layout = json.loads((ROOT / 'layouts' / 'fiber_align_array.json').read_text())
    g = with_live(ga.build_array(), True)
    served = {'/%s/%s' % (g.namespace, t) for t in graph_topics(g)} | {
        '/%s/live_view/%s' % (g.namespace, c) for c in ('alignment', 'optical_power_dbm')}
    assert lv.layout_topics(layout) <= served, sorted(lv.layout_topics(layout) - served)
    n = int(load_params(ao.CONFIG_FILE, ao.CONFIG_NODE)['channels'])
    labels = ao.model_labels(n)
    # the label a panel gives each index (the panel's text -> the model's label)
    meaning = {'x (m)': 'x_m', 'y (m)': 'y_m', 'roll (rad)': 'roll_rad'}
    meaning.update({'best ' + k: 'best_' + v for k, v in meaning.items()})
    meaning.update({'channel %d%s' % (i + 1, ' (measured)' if i in (0, n - 1) else ''):
                    'coupling_%d' % (i + 1) for i in range(n)})
    seen = set()
    for panel in layout['configById'].values():
        for path in panel.get('paths', ()):
            m = re.fullmatch(r'/array/array_model\.data\[(\d+)\]', path['value'])
            if m:
                assert labels[int(m.group(1))] == meaning[path['label']], path
                seen.add(labels[int(m.group(1))])
    assert seen == set(meaning.values())


def test_a_tap_sends_states_whole_and_samples_decimated_and_only_samples_are_lazy():
    state = lv.Tap('/s', 'std_msgs/msg/String', None, object(), True, None, None)
    assert not state.lazy and state.frames([], True, 0.0) == []     # nothing to resend
    assert state.frames([(b'a', {}), (b'b', {})], False, 0.0) == [b'a', b'b']
    assert state.frames([], True, 0.0) == [b'b'] and state.frames([], False, 0.0) == []
    sample = lv.Tap('/d', 'sensor_msgs/msg/JointState', None, object(), False,
                    lv.Decimator(100.0), None)
    assert sample.lazy
    assert sample.frames([(b'1', {}), (b'2', {})], False, 10.0) == [b'2']
    assert sample.frames([(b'3', {})], False, 10.001) == []         # within 10 ms: held back
    assert sample.frames([], True, 10.02) == [b'3']                 # resent: the newest
    # the power map's topics and a topic served for another channel only stay subscribed
    assert not lv.Tap('/x', 't', None, object(), False, lv.Decimator(100.0), 'x').lazy
    assert not lv.Tap('/p', 't', None, None, False, lv.Decimator(100.0), None).lazy
