# SPDX-License-Identifier: Apache-2.0
"""
Real hardware behind the graph, its emulators and the sensorless bench.

A Thorlabs MDT693B/MDT694B piezo amplifier (pyserial), a Thorlabs PM100 power meter
(pyvisa), emulators of both on this package's physics, and the sensorless bench.

Pure core: nothing here imports rclpy. ``pyserial``, ``pyvisa`` and ``pyvisa-py`` come
from the ``hardware`` extra (``pip install -e '.[hardware]'``). See docs/hardware.md.
"""
