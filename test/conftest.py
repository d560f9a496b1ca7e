# SPDX-License-Identifier: Apache-2.0
"""Shared test set-up: isolate every test process on its own ROS 2 domain."""

import os

# Discovery stays on this machine; no multicast leaves it.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
# Each pytest process gets a domain from its pid, so parallel runs (and helpers' runs)
# never see each other's nodes. Domains 1-100 are safe with Fast DDS port mapping.
if 'FIBER_ALIGN_TEST_KEEP_DOMAIN' not in os.environ:
    os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)
