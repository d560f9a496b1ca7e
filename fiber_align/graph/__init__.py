# SPDX-License-Identifier: Apache-2.0
"""
The fiber_align ROS graph described once, as data (pure Python: no rclpy).

- :mod:`.params`: node names, graph-wide values and the one law that merges params files;
- :mod:`.description`: processes, node names, params and lifecycle of the 1-D graph;
- :mod:`.rig`: the two-axis rig on that description;
- :mod:`.hardware`: the sensorless hardware bench on that description.

``ros2 launch``, ``bringup``, the demo, the benchmarks and the tests start graphs from it.
"""
