# SPDX-License-Identifier: Apache-2.0
"""``fiber-align design``: JSON output, plots and one-line errors (exit 2, no traceback)."""

import json

import pytest

from fiber_align.cli import main
from fiber_align.config import config_path, load_params, write_params


def _config(tmp_path, **changes):
    """Write the shipped Table 2 config with ``changes`` (None deletes a key); return path."""
    params = load_params(config_path('actuator.yaml'), node='actuator')
    for k, v in changes.items():
        if v is None:
            params.pop(k)
        else:
            params[k] = v
    p = tmp_path / 'act.yaml'
    write_params(p, 'actuator', params)
    return str(p)


def _error(capsys, argv):
    """Run the CLI expecting a usage error; return the single stderr line."""
    assert main(argv) == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert 'Traceback' not in err
    return lines[0]


def test_json_has_the_contract_keys(capsys):
    assert main(['design', '--config', 'actuator_table1.yaml', '--voltage', '100',
                 '--json']) == 0
    rep = json.loads(capsys.readouterr().out)
    for key in ('tip_displacement_m', 'blocked_force_n', 'blocked_force_rectangle_n',
                'first_mode_hz', 'stiffness_n_per_m', 'alpha_m_per_v', 'modal_mass_kg',
                'voltage_v', 'field_v_per_m'):
        assert isinstance(rep[key], float), key
    assert rep['voltage_v'] == 100.0
    assert rep['field_v_per_m'] == pytest.approx(100.0 / 125e-6)
    assert rep['tip_displacement_m'] == pytest.approx(85e-6, rel=0.03)


def test_default_voltage_is_v_max_and_table_is_readable(capsys):
    assert main(['design']) == 0
    out = capsys.readouterr().out
    assert '72.0 V' in out and 'blocked force trapezoid' in out and 'um' in out


@pytest.mark.ros  # starts a process
def test_plots_are_written(tmp_path, capsys):
    d = tmp_path / 'plots'
    assert main(['design', '--plots', str(d)]) == 0
    names = sorted(p.name for p in d.glob('*.png'))
    assert names == ['blocked_force.png', 'deflection.png', 'figure10_sweep_rh.png',
                     'figure7_sweep_A.png', 'figure8_sweep_L.png', 'figure9_sweep_hp.png']
    assert all((d / n).stat().st_size > 5000 for n in names)


def test_missing_file(capsys, tmp_path):
    line = _error(capsys, ['design', '--config', str(tmp_path / 'nope.yaml')])
    assert '--config' in line and 'nope.yaml' in line


def test_unknown_key(capsys, tmp_path):
    line = _error(capsys, ['design', '--config', _config(tmp_path, base_widht_m=8e-3)])
    assert 'base_widht_m' in line and 'allowed keys' in line


def test_missing_key(capsys, tmp_path):
    line = _error(capsys, ['design', '--config', _config(tmp_path, metal_modulus_pa=None)])
    assert 'missing' in line and 'metal_modulus_pa' in line


@pytest.mark.parametrize('key', ['piezo_thickness_m', 'tip_width_m', 'piezo_length_m'])
def test_non_positive_dimension(capsys, tmp_path, key):
    line = _error(capsys, ['design', '--config', _config(tmp_path, **{key: 0.0})])
    assert key in line and 'allowed: > 0' in line


def test_l0_shorter_than_l(capsys, tmp_path):
    line = _error(capsys, ['design', '--config', _config(tmp_path, total_length_m=10.5e-3)])
    assert 'total_length_m' in line and 'L0 >= L' in line


def test_voltage_above_field_limit(capsys):
    line = _error(capsys, ['design', '--voltage', '151'])
    assert '--voltage' in line and '0..150 V' in line and 'max_field_v_per_m' in line


def test_negative_voltage(capsys):
    line = _error(capsys, ['design', '--voltage', '-5'])
    assert '--voltage' in line and 'allowed' in line


def test_v_max_beyond_field_limit_is_refused(capsys, tmp_path):
    line = _error(capsys, ['design', '--config', _config(tmp_path, v_max=200.0)])
    assert 'v_max' in line and '150 V' in line


def test_unwritable_plot_dir(capsys, tmp_path):
    f = tmp_path / 'file'
    f.write_text('x')
    line = _error(capsys, ['design', '--plots', str(f / 'sub')])
    assert '--plots' in line


def test_yaml_exponent_without_sign_is_explained(capsys, tmp_path):
    p = tmp_path / 'act.yaml'
    text = config_path('actuator.yaml').read_text().replace('83.0e+9', '83.0e9')
    p.write_text(text)
    line = _error(capsys, ['design', '--config', str(p)])
    assert 'piezo_modulus_pa' in line and 'must be a number' in line and 'e+' in line
