# SPDX-License-Identifier: Apache-2.0
"""The multi-axis run's summary (``analysis.axes_summary``): figures per axis, the report."""

from fiber_align.analysis.axes_summary import axis_figures, print_report


def test_each_axis_gets_the_figures_of_its_own_nodes_only():
    by_status = {
        'latest': {'/rig/x/simulated_actuator': {'missed_share': '0.01'},
                   '/rig/x/actuator_driver': {'watchdog_count': '2'},
                   '/rig/y/simulated_actuator': {'missed_share': '0.5'},
                   '/rig/optics': {'missed_share': '0.9'}},
        'worst': {'/rig/y/simulated_actuator': {'missed_share': 0.7}}}
    out = axis_figures(by_status, '/rig', ('x', 'y'))
    assert out['x']['missed_share'] == 0.01 and out['x']['watchdog_count'] == 2
    assert out['y']['missed_share'] == 0.5 and 'watchdog_count' not in out['y']
    assert out['x']['worst'] == {}
    assert out['y']['worst'] == {'simulated_actuator': {'missed_share': 0.7}}
    # without a namespace the axes are top-level
    bare = axis_figures({'latest': {'/x/simulated_actuator': {'missed_share': '0.2'}},
                         'worst': {}}, '', ('x',))
    assert bare['x']['missed_share'] == 0.2


def test_the_report_names_a_different_offline_run(capsys):
    print_report({'scenario': 'align2d', 'sync_mode': 'lockstep', 'seed': 0,
                  'state': 'TRACKING', 'align_sample': 300, 'time_to_peak_s': 0.068,
                  'peak_samples': 58,
                  'offline': {'samples': 10, 'max_abs_mx': 1e-9, 'max_abs_my': 0.0,
                              'max_abs_rx': 0.0, 'max_abs_ry': 0.0, 'max_rel_p': 0.0,
                              'equal': False}})
    out = capsys.readouterr().out
    assert 'time to peak 68.0 ms' in out and 'DIFFERENT' in out and '1e-09 m' in out
