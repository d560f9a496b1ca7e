# SPDX-License-Identifier: Apache-2.0
"""
The graph's rosbag2 bags (mcap and sqlite3), read and written with rosbags, fast.

- :mod:`~fiber_align.analysis.bag.common`: message types, :data:`GRAPH_TOPICS`, topic
  discovery by last name, :class:`Stream`, :class:`BagError`;
- :mod:`~fiber_align.analysis.bag.cdr`: vectorised CDR encoding of the fixed layouts;
- :mod:`~fiber_align.analysis.bag.decode`: vectorised decoding (rosbags as fallback);
- :mod:`~fiber_align.analysis.bag.reader`: :class:`BagReader`, :func:`read_streams`,
  :func:`read_hysteresis_experiment`;
- :mod:`~fiber_align.analysis.bag.writer`: :func:`write_bag`;
- :mod:`~fiber_align.analysis.bag.packer`: an rclpy message's CDR by a plan per type;
- :mod:`~fiber_align.analysis.bag.sink`: a recorder's bag, counts and flight keepers;
- :mod:`~fiber_align.analysis.bag.guard`: a bag that survives a full disk;
- :mod:`~fiber_align.analysis.bag.flight`: the flight recorder's rings and snapshots.

Times are int64 ns, values SI (m, m/s, V, W).
"""

from fiber_align.analysis.bag.cdr import (encode_clock, encode_float64, encode_joint_state,
                                          encode_multiarray, joint_state_template,
                                          multiarray_template)
from fiber_align.analysis.bag.common import (BagError, CLOCK, CONTROLLER_LABELS, DIAGNOSTICS,
                                             discover, FLOAT64, GRAPH_TOPICS, JOINT_STATE,
                                             last_name, MULTI_ARRAY, storage_plugin, Stream,
                                             STRING, typestore)
from fiber_align.analysis.bag.reader import BagReader, read_hysteresis_experiment, read_streams
from fiber_align.analysis.bag.writer import write_bag

__all__ = ['BagError', 'BagReader', 'CLOCK', 'CONTROLLER_LABELS', 'DIAGNOSTICS', 'discover',
           'encode_clock', 'encode_float64', 'encode_joint_state', 'encode_multiarray',
           'FLOAT64', 'GRAPH_TOPICS', 'JOINT_STATE', 'joint_state_template', 'last_name',
           'MULTI_ARRAY', 'multiarray_template', 'read_hysteresis_experiment',
           'read_streams', 'storage_plugin', 'Stream', 'STRING', 'typestore', 'write_bag']
