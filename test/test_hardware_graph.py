# SPDX-License-Identifier: Apache-2.0
"""The sensorless hardware graph (processes of ``build_hardware``) on the emulators."""

from fiber_align.nodes.bringup.hardware import graph_trial


def test_sensorless_graph_aligns_on_the_emulators():
    r = graph_trial(seed=5, slot_m=41e-6)
    assert r['aligned'], r['status']
    assert r['align_wall_s'] <= 3.0, r
    assert r['final_loss_db'] < 0.1, r
    lo, hi = r['v_range']
    assert 0.0 <= lo and hi <= 100.0 and r['commands'] > 50
    assert all(code == 0 for code in r['exit_codes'].values()), r['exit_codes']
