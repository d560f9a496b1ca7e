# SPDX-License-Identifier: Apache-2.0
"""
A params file out of a declared range is refused before any process starts (issue 39.6).

:func:`fiber_align.graph.arguments.describe` (the launch file and ``bringup``) checks every
value of every node of the graph against the range the node declares
(:mod:`fiber_align.graph.ranges`, the nodes' own tables: ``test_nodes_ranges.py``) and
each driver's limits against the field limits and the amplifier's. Before, such a file
was accepted here and one process exited at its start while the others waited for it.
Also :class:`fiber_align.graph.startup.StartupWatch`: the line that ends a launch when a
process exits during start-up.
"""

import pytest

from fiber_align.graph.arguments import describe
from fiber_align.graph.params import GraphError
from fiber_align.graph.ranges import range_of
from fiber_align.graph.refusals import check_graph, core_keys
from fiber_align.graph.startup import STARTUP_DONE, StartupWatch

#: name -> (params file text, words of the refusal)
BAD = {
    'rate': ('/**:\n  ros__parameters:\n    rate_hz: -1000\n',
             'rate_hz=-1000 is out of range [1, 20000]'),
    'watchdog': ('actuator_driver:\n  ros__parameters:\n    watchdog_timeout_s: -0.5\n',
                 'watchdog_timeout_s=-0.5 is out of range [0, 60]'),
    'v_max': ('actuator_driver:\n  ros__parameters:\n    v_max: 120.0\n',
              "v_max=120 V, v_min=-20 V: outside the amplifier's limits [-20, 100] V"),
}
MACHINES = ({}, {'rig': 'true'}, {'station': 'true'}, {'hardware': 'true'},
            {'rig': 'true', 'hardware': 'true'})


def _file(tmp_path, text, name='user.yaml'):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize('args', MACHINES)
def test_every_shipped_graph_passes_its_own_check(args):
    check_graph(describe(args))


@pytest.mark.parametrize('name', sorted(BAD))
def test_a_value_out_of_its_range_is_refused_in_one_line(tmp_path, name):
    text, words = BAD[name]
    with pytest.raises(GraphError) as err:
        describe({'params_file': _file(tmp_path, text)})
    line = str(err.value)
    assert words in line and '\n' not in line, line


@pytest.mark.parametrize('args', MACHINES[:4])
def test_the_rate_is_checked_in_every_graph(tmp_path, args):
    with pytest.raises(GraphError, match=r'rate_hz=-1000 is out of range'):
        describe(dict(args, params_file=_file(tmp_path, BAD['rate'][0])))


def test_the_hardware_rig_checks_its_amplifier_node(tmp_path):
    f = _file(tmp_path, 'mdt693b_driver:\n  ros__parameters:\n    watchdog_timeout_s: -1.0\n')
    with pytest.raises(GraphError, match=r'/rig/mdt693b_driver: watchdog_timeout_s=-1.0'):
        describe({'rig': 'true', 'hardware': 'true', 'params_file': f})


def test_the_axes_of_a_rig_are_each_checked(tmp_path):
    f = _file(tmp_path, 'y/actuator_driver:\n  ros__parameters:\n    v_max: 101.0\n')
    with pytest.raises(GraphError, match=r'/rig/y/actuator_driver: v_max=101 V'):
        describe({'rig': 'true', 'params_file': f})


@pytest.mark.parametrize('text, words', [
    # the MDT693B's highest limit switch is 150 V
    ('actuator_driver:\n  ros__parameters:\n    v_max: 149.0\n    field_limit_v: 200.0\n'
     '    device_limit_v: 75.0\n', "v_max=149 V is above the amplifier's limit 75 V"),
    ('actuator_driver:\n  ros__parameters:\n    v_max: 160.0\n    field_limit_v: 200.0\n',
     "v_max=160 V is above the amplifier's limit 150 V"),
    ('actuator_driver:\n  ros__parameters:\n    v_max: 200.0\n',
     'v_max 200 V exceeds the field limit 150 V'),
])
def test_the_hardware_drive_limit_is_the_amplifiers(tmp_path, text, words):
    with pytest.raises(GraphError) as err:
        describe({'hardware': 'true', 'params_file': _file(tmp_path, text)})
    assert words in str(err.value), str(err.value)


def test_a_value_the_node_takes_is_taken(tmp_path):
    f = _file(tmp_path, 'actuator_driver:\n  ros__parameters:\n    v_max: 90.0\n'
              '    watchdog_timeout_s: 0.0\n/**:\n  ros__parameters:\n    rate_hz: 2000\n')
    g = describe({'params_file': f})
    assert g.node_params('actuator_driver')['v_max'] == 90.0


def test_ranges_follow_each_nodes_declarations():
    assert range_of('simulated_actuator', 'rate_hz')[1:] == (1.0, 20000.0)
    assert range_of('power_meter', 'rate_hz')[1:] == (0.1, 1000.0)    # its own
    assert range_of('mdt693b_driver', 'x.v_max')[1:] == (-1000.0, 1000.0)
    assert range_of('fuzzy_pid_controller', 'pid.kp')[1:] == (-1e12, 1e12)
    seq = {'machine': '1d', 'search_timeout_s': 5.0}
    core = core_keys('alignment_sequencer', seq)
    assert range_of('alignment_sequencer', 'search_timeout_s', seq, core)[1:] == (0.0, 3600.0)
    assert range_of('alignment_sequencer', 'search_timeout_s', seq) is None   # not its core
    assert range_of('simulated_actuator', 'hysteresis') is None


def test_an_exit_during_start_up_ends_the_launch_with_the_childs_last_line():
    w = StartupWatch()
    w.output('control_graph', b'[INFO] starting\n[ERROR] fuzzy_pid_controller: u_max=1 V\n')
    assert w.exit_reason('control_graph', 2) == (
        'control_graph exited with code 2 during start-up: '
        '[ERROR] fuzzy_pid_controller: u_max=1 V')
    assert w.exit_reason('scenario_runner', 0, ends_graph=True) is None
    assert w.exit_reason('control_graph', -2, shutting_down=True) is None
    w.output('lifecycle_manager', '[INFO] %s in 0.2 s: actuator_driver active' % STARTUP_DONE)
    assert w.done and w.exit_reason('control_graph', 1) is None     # later: left running
