# SPDX-License-Identifier: Apache-2.0
"""The rclpy message class of a ROS type name (the nodes' side of bag recording)."""

import importlib


def message_class(msgtype):
    """Return the rclpy message class of a type string such as ``std_msgs/msg/Float64``."""
    pkg, sub, name = msgtype.split('/')
    return getattr(importlib.import_module('%s.%s' % (pkg, sub)), name)
