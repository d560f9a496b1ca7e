# SPDX-License-Identifier: Apache-2.0
"""ROS infrastructure of the fiber_align nodes: parameters, QoS, diagnostics, bus, runtime."""
