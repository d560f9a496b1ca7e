# SPDX-License-Identifier: Apache-2.0
"""
Real hardware behind the graph: a Thorlabs MDT693B/MDT694B piezo amplifier (pyserial) and
a Thorlabs PM100 power meter (pyvisa), their emulators and the sensorless bench.

Pure core: nothing here imports rclpy. ``pyserial``, ``pyvisa`` and ``pyvisa-py`` come
from the ``hardware`` extra (``pip install -e '.[hardware]'``). See docs/hardware.md.
"""
