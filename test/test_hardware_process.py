# SPDX-License-Identifier: Apache-2.0
"""Tests of :mod:`fiber_align.hardware.process`: the options of ``fiber-align emulate``."""

from fiber_align.hardware.process import emulator_options


def test_the_options_of_a_run_are_the_emulate_command_line():
    assert emulator_options(3) == ['--seed', '3']
    rig = emulator_options(0, (2.5e-05, 4e-05))
    assert rig == ['--seed', '0', '--rig', '--target-x', '2.5e-05', '--target-y', '4e-05']
    one = emulator_options(7, slot_m=4.1e-05, meter_floor_w=1e-9)
    assert one == ['--seed', '7', '--slot', '4.1e-05', '--meter-floor', '1e-09']
