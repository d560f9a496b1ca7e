# SPDX-License-Identifier: Apache-2.0
"""The recorder catch-up rule (``analysis.recording``) on hand-made /diagnostics reports."""

from types import SimpleNamespace

from fiber_align.analysis.recording import diag_entry, left_text, recorder_missing
from fiber_align.analysis.recording import recorder_short


def _report(t, **values):
    return dict({k.replace('__', '.'): str(v) for k, v in values.items()}, _t=t)


def _diag(t_nodes=2.0, t_rec=2.0, recorded=50, drive_recorded=50):
    return {
        'simulated_actuator': _report(t_nodes, sent__displacement=50),
        'actuator_driver': _report(t_nodes, sent__drive_voltage=50),
        'scenario_runner': _report(t_nodes, sent__setpoint=50),   # recorded as reference
        'lifecycle_manager': _report(t_nodes),
        'bag_recorder': {'recorded./displacement': str(recorded),
                         'recorded./drive_voltage': str(drive_recorded),
                         'recorded./alignment_state': '0', '_t': t_rec},
    }


def test_caught_up_when_every_sent_count_is_recorded():
    assert recorder_short(_diag(), since=1.0) == {}
    assert recorder_missing(_diag(), since=1.0) == []


def test_short_names_the_topic_and_its_counts():
    assert recorder_short(_diag(recorded=48), since=1.0) == {'displacement': (48, 50)}
    # a topic sent on but not subscribed yet (recorded 0) is missing; one behind is not
    d = _diag(recorded=48, drive_recorded=0)
    assert recorder_missing(d, since=1.0) == ['drive_voltage']


def test_reports_from_before_since_do_not_count():
    assert recorder_short(_diag(t_rec=0.5), since=1.0) is None
    assert recorder_short(_diag(t_nodes=0.5), since=1.0) is None
    assert recorder_missing(_diag(t_nodes=0.5), since=1.0) is None
    # the nodes asked for: a stale node outside them changes nothing
    d = _diag()
    d['actuator_driver']['_t'] = 0.5
    assert recorder_short(d, since=1.0, names=['simulated_actuator']) == {}


def test_without_a_recorder_report_nothing_is_known():
    d = _diag()
    del d['bag_recorder']
    assert recorder_short(d, since=1.0) is None


def test_a_status_is_kept_by_its_node_base_name_with_level_message_and_arrival():
    """Both readers (bringup, scenario_runner) keep a status the same way."""
    kv = [SimpleNamespace(key='sent.displacement', value='50'),
          SimpleNamespace(key='recorded./displacement', value='49')]
    for level in (b'\x02', 2):             # rclpy gives bytes; a hand-made status an int
        st = SimpleNamespace(name='/ns/bag_recorder', level=level, message='lost 1',
                             values=kv)
        node, values = diag_entry(st, 7.5)
        assert node == 'bag_recorder'
        assert values == {'level': 2, 'message': 'lost 1', '_t': 7.5,
                          'sent.displacement': '50', 'recorded./displacement': '49'}
    diag = {'bag_recorder': diag_entry(st, 3.0)[1], 'simulated_actuator': _report(
        3.0, sent__displacement=50)}
    assert recorder_short(diag, 2.0) == {'displacement': (49, 50)}


def test_left_text_says_what_the_recorder_lacks():
    assert left_text(None) == 'no fresh /diagnostics reports'
    assert left_text({'/b': (3, 5), '/a': (0, 2)}) == '/a 0 of 2, /b 3 of 5'
    assert left_text(['/setpoint']) == 'nothing of /setpoint'
