# SPDX-License-Identifier: Apache-2.0
"""``python -m fiber_align.demo --quick``: scenarios run, are recorded and analysed."""

import json
import sys

import pytest

from procs import run_bounded

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_quick_demo_records_analyses_and_aligns(tmp_path):
    """
    Sine and align + switch, one process per node (the demo's default is composed).

    Bags, reports, figures, the table, and numbers in range; the demo's orchestration
    is the same for every scenario (the step is tested in test_bringup_lockstep.py), and
    ``--composed`` in test_bringup_lockstep.py, so two scenarios keep the test short.
    """
    out = tmp_path / 'demo'
    code, text = run_bounded([sys.executable, '-m', 'fiber_align.demo', '--quick', '--out',
                              str(out), '--scenarios', 'sine,align', '--multi-process'],
                             timeout=180, grace_s=20.0)
    assert code == 0, text
    rows = {r['scenario']: r for r in json.loads(
        (out / 'summary.json').read_text(encoding='utf-8'))['rows']}
    assert list(rows) == ['sine', 'align']
    for name, r in rows.items():
        assert r['ok'], r
        assert (out / name / 'bag' / 'metadata.yaml').is_file()
        assert (out / name / 'report.md').is_file()
        assert list((out / name / 'figures').glob('*.png'))
    assert rows['sine']['samples'] == 300
    assert 0 < float(rows['sine']['rms_error_m']) < 5e-6
    align = rows['align']
    assert align['state'] == 'TRACKING'
    assert 0 <= align['loss_db'] < 0.05 and 0 <= align['cycle_loss_max_db'] < 0.1
    assert '| align |' in text and 'summary:' in text
