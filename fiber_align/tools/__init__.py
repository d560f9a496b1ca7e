# SPDX-License-Identifier: Apache-2.0
"""The command-line tools' sub-commands (the top layer, beside the ROS nodes)."""
