# SPDX-License-Identifier: Apache-2.0
"""Bag reading and writing: fast numpy decoding equals rosbags' own deserialisation."""

import numpy as np
import pytest

from fiber_align.analysis import bag as bagio


def _series(n=1500):
    k = np.arange(n)
    t = k * 1_000_000
    recv = 1_700_000_000_000_000_000 + 2 * t
    rng = np.random.default_rng(1)
    return {
        'clock': {'t_ns': recv, 'clock_ns': t},
        'displacement': {'t_ns': recv + 1, 'stamp_ns': t, 'position': rng.normal(size=n) * 1e-6,
                         'velocity': rng.normal(size=n) * 1e-3},
        'setpoint': {'t_ns': recv + 2, 'data': rng.normal(size=n) * 1e-6},
        'drive_voltage': {'t_ns': recv + 3, 'data': rng.uniform(0, 100, n)},
        'controller_state': {'t_ns': recv + 4, 'data': rng.normal(size=(n, 6))},
        'alignment_state': {'t_ns': recv[:3], 'data': ['search', 'lock', 'track']},
    }


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_roundtrip_fast_path_matches_input(tmp_path, storage):
    """write_bag then read_streams returns the arrays bit for bit, under a namespace."""
    s = _series()
    bagio.write_bag(tmp_path / 'b', s, storage=storage, namespace='/rig7')
    streams, lockstep, topics = bagio.read_streams(tmp_path / 'b')
    assert lockstep
    assert '/rig7/displacement' in topics and '/clock' in topics
    d = streams['displacement']
    assert d.decoder == 'numpy'
    assert np.array_equal(d.fields['stamp_ns'], s['displacement']['stamp_ns'])
    assert np.array_equal(d.fields['position'], s['displacement']['position'])
    assert np.array_equal(d.fields['velocity'], s['displacement']['velocity'])
    assert np.array_equal(d.t_ns, s['displacement']['t_ns'])
    assert np.array_equal(streams['setpoint'].fields['data'], s['setpoint']['data'])
    assert np.array_equal(streams['controller_state'].fields['data'],
                          s['controller_state']['data'])
    assert streams['controller_state'].labels == bagio.CONTROLLER_LABELS
    assert [m.data for m in streams['alignment_state'].fields['msgs']] == \
        ['search', 'lock', 'track']


def test_encoders_match_rosbags_serializer():
    """The vectorised CDR encoders produce exactly rosbags' serialisation."""
    ts = bagio.typestore()
    f64 = ts.types[bagio.FLOAT64](data=1.25e-6)
    assert bagio.encode_float64([1.25e-6])[0].tobytes() == bytes(
        ts.serialize_cdr(f64, bagio.FLOAT64))
    row = bagio.encode_joint_state([3_000_000_004], [2e-6], [0.5])[0].tobytes()
    m = ts.deserialize_cdr(row, bagio.JOINT_STATE)
    assert (m.header.stamp.sec, m.header.stamp.nanosec) == (3, 4)
    assert list(m.name) == ['bimorph_tip'] and m.position[0] == 2e-6 and m.velocity[0] == 0.5
    row = bagio.encode_multiarray(np.arange(6.0)[None])[0].tobytes()
    m = ts.deserialize_cdr(row, bagio.MULTI_ARRAY)
    assert [d.label for d in m.layout.dim] == list(bagio.CONTROLLER_LABELS)
    assert list(m.data) == list(range(6))


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_bag_from_plain_rosbags_with_varying_layout(tmp_path, storage):
    """
    A bag written message by message with rosbags (other tool) reads the same.

    The joint names change half way, so the JointState layout is not fixed and the
    reader must fall back to rosbags' deserialiser for those batches.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    ts = bagio.typestore()
    JS, F64 = ts.types[bagio.JOINT_STATE], ts.types[bagio.FLOAT64]
    Header, Time = ts.types['std_msgs/msg/Header'], ts.types['builtin_interfaces/msg/Time']
    n = 300
    plug = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(tmp_path / 'o', version=9, storage_plugin=plug) as w:
        cd = w.add_connection('/a/b/displacement', bagio.JOINT_STATE, typestore=ts)
        cs = w.add_connection('/a/b/setpoint', bagio.FLOAT64, typestore=ts)
        for i in range(n):
            names = ['bimorph_tip'] if i < n // 2 else ['tip', 'other']
            pos = np.array([i * 1e-8] + [0.0] * (len(names) - 1))
            m = JS(header=Header(stamp=Time(sec=i // 1000, nanosec=(i % 1000) * 1000000),
                                 frame_id='base'), name=names, position=pos,
                   velocity=np.zeros(len(names)), effort=np.zeros(0))
            w.write(cd, 10 + i * 1000, ts.serialize_cdr(m, bagio.JOINT_STATE))
            w.write(cs, 11 + i * 1000, ts.serialize_cdr(F64(data=i * 2e-8), bagio.FLOAT64))
    streams, lockstep, _ = bagio.read_streams(tmp_path / 'o')
    assert not lockstep
    d = streams['displacement']
    assert np.array_equal(d.fields['position'], np.arange(n) * 1e-8)
    assert np.array_equal(d.fields['stamp_ns'], np.arange(n) * 1000000)
    assert np.array_equal(streams['setpoint'].fields['data'], np.arange(n) * 2e-8)
    assert np.array_equal(streams['setpoint'].t_ns, 11 + np.arange(n) * 1000)


def test_rclpy_serialised_messages_with_garbage_padding_use_fast_path(tmp_path):
    """Decode rclpy serialisations (garbage padding) on the fast path."""
    import rclpy.serialization as ser
    from rosbags.rosbag2 import StoragePlugin, Writer
    from sensor_msgs.msg import JointState
    ts = bagio.typestore()
    with Writer(tmp_path / 'r', version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection('/displacement', bagio.JOINT_STATE, typestore=ts)
        for i in range(50):
            m = JointState(name=['bimorph_tip'], position=[i * 1e-6], velocity=[1.0])
            m.header.stamp.nanosec = i
            w.write(c, i, ser.serialize_message(m))
    with bagio.BagReader(tmp_path / 'r') as bag:
        d = bag.read('displacement')
    assert d.decoder == 'numpy'
    assert np.array_equal(d.fields['position'], np.arange(50) * 1e-6)


def test_hysteresis_experiment_reader(tmp_path):
    """read_hysteresis_experiment returns (t, u, y) aligned sample by sample."""
    n = 400
    k = np.arange(n)
    u = 72.0 * (1 - np.abs(k / 200.0 - 1))
    y = 1e-6 * u
    recv = 10_000 + k * 1_000_000
    bagio.write_bag(tmp_path / 'h', {
        'displacement': {'t_ns': recv, 'stamp_ns': k * 1_000_000, 'position': y},
        'drive_voltage': {'t_ns': recv + 500, 'data': u}})
    t, uu, yy = bagio.read_hysteresis_experiment(tmp_path / 'h')
    assert np.allclose(t, k * 1e-3, rtol=0, atol=1e-15)
    assert np.array_equal(uu, u) and np.array_equal(yy, y)


def test_missing_and_corrupt_bags_raise_bag_error(tmp_path):
    """Absent, truncated and corrupt bags give one BagError naming the bag."""
    with pytest.raises(bagio.BagError, match='does not exist'):
        bagio.BagReader(tmp_path / 'nope')
    bagio.write_bag(tmp_path / 'c', {'setpoint': {'t_ns': np.arange(5000),
                                                  'data': np.arange(5000.0)}})
    f = tmp_path / 'c' / 'c.mcap'
    raw = f.read_bytes()
    f.write_bytes(raw[:len(raw) // 2])
    with pytest.raises(bagio.BagError, match='cannot read bag'):
        bagio.read_streams(tmp_path / 'c')
