# SPDX-License-Identifier: Apache-2.0
"""
The fiber_align ROS graph described once, as data (pure Python: no rclpy).

- :mod:`.params`: node names, graph-wide values and the one law that merges params files;
- :mod:`.registry`: every node (executable, class, params files, topics), the enumerations;
- :mod:`.description`: processes, node names, params and lifecycle of the 1-D graph;
- :mod:`.rig`, :mod:`.station`: the two-axis rig and the coupled station on it;
- :mod:`.hardware`, :mod:`.hardware_rig`: the sensorless hardware bench, the rig on it;
- :mod:`.live`: any of them with the live view;
- :mod:`.arguments`: ``describe``, the one step from launch arguments to one of them.

``ros2 launch``, ``bringup``, the demo, the benchmarks and the tests start graphs from it.
"""
