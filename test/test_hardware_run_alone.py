# SPDX-License-Identifier: Apache-2.0
"""
The hardware nodes run alone, as docs/hardware.md's ``ros2 run`` lines write them.

Each node is its own process (``python -m fiber_align.nodes.<name> --ros-args ...``, what
``ros2 run fiber_align <name>`` runs) with only the arguments the documented line gives,
on the emulators: the MDT693B emulator in this process (its command log shows what
arrived), the PM100 behind ``fiber-align emulate``. A client in this process drives the
driver's lifecycle (``change_state``, as ``ros2 lifecycle set``), publishes its inputs
(30 V of feedforward, 0 V of feedback) and listens. Each
node runs once without a params file and once after ``--params-file
config/hardware.yaml``: a ``-p`` on the command line must win over the file.
"""

import os
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.srv import ChangeState
import pytest
from rcl_interfaces.srv import GetParameters
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

from fiber_align.config import config_path
from fiber_align.hardware.bench import emulated
from fiber_align.hardware.process import start_emulator, stop_process
import procs

pytestmark = pytest.mark.ros

#: The shipped params file of the documented ``--params-file`` lines.
HARDWARE_YAML = str(config_path('hardware.yaml'))
#: Extra arguments before the ``-p`` ones: none, or the shipped file.
FILES = {'alone': (), 'params_file': ('--params-file', HARDWARE_YAML)}
#: s: bound of every wait (a process's start, discovery, a service call).
BOUND_S = 30.0
#: Offers every subscription its QoS (reliable and transient-local cover all kinds).
PUB_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Accepts every publisher's QoS.
SUB_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT,
                     durability=DurabilityPolicy.VOLATILE)


def spawn(name, log_dir, ros_args):
    """Start node ``name`` as ``ros2 run`` would, its output in ``log_dir``; a Popen."""
    log = open(os.path.join(str(log_dir), '%s.log' % name), 'w')
    try:
        return subprocess.Popen(
            [sys.executable, '-m', 'fiber_align.nodes.%s' % name, '--ros-args', *ros_args],
            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    finally:
        log.close()


def log_of(name, log_dir):
    """Return the output of node ``name`` so far (for the failure messages)."""
    with open(os.path.join(str(log_dir), '%s.log' % name)) as f:
        return f.read()[-3000:]


class Probe:
    """An rclpy node in a context of its own, spun by :meth:`until`."""

    def __init__(self):
        """Create the context, the node and its executor."""
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, args=['probe'])
        self.node = rclpy.create_node('run_alone_probe', context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)

    def until(self, cond, bound_s=BOUND_S):
        """Spin until ``cond()`` or ``bound_s`` (s) passed; return ``cond()``."""
        return procs.spin_until(self.ex, cond, bound_s, 0.02)

    def call(self, cli, req, bound_s=BOUND_S):
        """Call a service (waiting for it first); return the response or None."""
        if not self.until(cli.service_is_ready, bound_s):
            return None
        fut = cli.call_async(req)
        self.until(fut.done, bound_s)
        return fut.result() if fut.done() else None

    def close(self):
        """Destroy the node and the context."""
        self.ex.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def transition(probe, cli, tid):
    """Ask for lifecycle transition ``tid``; return its success (None: no answer)."""
    req = ChangeState.Request()
    req.transition.id = tid
    res = probe.call(cli, req)
    return None if res is None else res.success


@pytest.mark.parametrize('files', sorted(FILES))
def test_driver_with_backend_and_port_only_configures_activates_and_drives(files, tmp_path):
    """``actuator_driver --ros-args -p backend:=mdt693b -p port:=<link>``: commands arrive."""
    with emulated(seed=0) as (_, mdt, _pm):
        proc = spawn('actuator_driver', tmp_path, FILES[files] + (
            '-p', 'backend:=mdt693b', '-p', 'port:=%s' % mdt.port))
        probe = None
        try:
            probe = Probe()
            n = probe.node
            readback = []
            n.create_subscription(Float64, '/drive_voltage_readback',
                                  lambda m: readback.append(m.data), SUB_QOS)
            ff = n.create_publisher(Float64, '/feedforward_voltage', PUB_QOS)
            # the feedback law's place (without the file the driver is not sensorless)
            fb = n.create_publisher(Float64, '/feedback_voltage', PUB_QOS)
            change = n.create_client(ChangeState, '/actuator_driver/change_state')
            get = n.create_client(GetParameters, '/actuator_driver/get_parameters')
            res = probe.call(get, GetParameters.Request(names=['v_min', 'v_max', 'port']))
            assert res is not None, log_of('actuator_driver', tmp_path)
            v_min, v_max, port = res.values
            # the backend's own limits, and the port given (not the file's /dev/ttyUSB0)
            assert (v_min.double_value, v_max.double_value) == (0.0, 100.0)
            assert port.string_value == mdt.port
            assert transition(probe, change, 1), log_of('actuator_driver', tmp_path)
            assert transition(probe, change, 3), log_of('actuator_driver', tmp_path)
            t0 = time.monotonic()

            def arrived():
                ff.publish(Float64(data=30.0))
                fb.publish(Float64(data=0.0))
                sent = [v for t, ch, _, v in list(mdt.command_log) if t > t0 and ch == 'x']
                return sent and abs(sent[-1] - 30.0) < 1e-6 and readback \
                    and abs(readback[-1] - 30.0) < 0.5
            assert probe.until(arrived, 10.0), (
                mdt.command_log[-5:], readback[-5:], log_of('actuator_driver', tmp_path))
            sent = [v for t, _, _, v in list(mdt.command_log) if t > t0]
            assert all(0.0 <= v <= 100.0 for v in sent)
            assert transition(probe, change, 4)         # deactivate: ramps to 0 V
            assert abs(mdt.command_log[-1][3]) < 1e-9
        finally:
            if probe is not None:
                probe.close()
            procs.stop(proc)
        assert proc.returncode == 0, log_of('actuator_driver', tmp_path)


def test_driver_mdt693b_refuses_an_explicit_v_min_below_0_v(tmp_path):
    """The user's value wins over the backend's, and a v_min < 0 V is still refused."""
    with emulated(seed=0) as (_, mdt, _pm):
        proc = spawn('actuator_driver', tmp_path, (
            '-p', 'backend:=mdt693b', '-p', 'port:=%s' % mdt.port, '-p', 'v_min:=-5.0'))
        probe = None
        try:
            probe = Probe()
            change = probe.node.create_client(ChangeState, '/actuator_driver/change_state')
            assert transition(probe, change, 1) is False
            assert not mdt.command_log
        finally:
            if probe is not None:
                probe.close()
            procs.stop(proc)
        assert 'v_min -5 V is below 0 V, which the MDT693B cannot output' in \
            log_of('actuator_driver', tmp_path)


@pytest.mark.parametrize('files', sorted(FILES))
def test_power_meter_with_resource_only_reads_the_resource_given(files, tmp_path):
    """``power_meter --ros-args [--params-file hardware.yaml] -p resource:=<emulator>``."""
    emu, info = start_emulator(('--seed', '1', '--slot', '0'))
    proc = probe = None
    try:
        resource = info['visa_resource']
        proc = spawn('power_meter', tmp_path, FILES[files] + (
            '-p', 'resource:=%s' % resource))
        probe = Probe()
        got, ids = [], []
        probe.node.create_subscription(Float64, '/optical_power',
                                       lambda m: got.append(m.data), SUB_QOS)
        probe.node.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda m: ids.extend((procs.level(s), s.hardware_id) for s in m.status
                                 if s.name == '/power_meter'), SUB_QOS)
        assert probe.until(lambda: len(got) >= 20 and ids and ids[-1][0] == 0), (
            ids[-3:], log_of('power_meter', tmp_path))
        assert ids[-1][1] == resource
        assert all(p > 0.0 for p in got)
    finally:
        if probe is not None:
            probe.close()
        if proc is not None:
            procs.stop(proc)
        stop_process(emu)
    assert proc.returncode == 0, log_of('power_meter', tmp_path)


def test_driver_whose_launcher_died_ramps_to_0_v_and_exits_0(tmp_path):
    """
    The launcher gone (its output pipe without a reader), SIGTERM: ramped to 0 V, exit 0.

    ``ros2 launch`` reads its processes' output through pipes; killed with SIGKILL, it
    leaves them without a reader. The driver's exit report then meets a broken pipe: the
    stop must still ramp the amplifier to its safe voltage and end in order.
    """
    with emulated(seed=0) as (_, mdt, _pm):
        err = open(tmp_path / 'stderr.log', 'w')
        proc = subprocess.Popen(
            [sys.executable, '-m', 'fiber_align.nodes.actuator_driver', '--ros-args',
             '-p', 'backend:=mdt693b', '-p', 'port:=%s' % mdt.port],
            stdout=subprocess.PIPE, stderr=err, start_new_session=True)
        err.close()
        probe = None
        try:
            probe = Probe()
            n = probe.node
            ff = n.create_publisher(Float64, '/feedforward_voltage', PUB_QOS)
            fb = n.create_publisher(Float64, '/feedback_voltage', PUB_QOS)
            change = n.create_client(ChangeState, '/actuator_driver/change_state')
            assert transition(probe, change, 1), (tmp_path / 'stderr.log').read_text()
            assert transition(probe, change, 3)
            t0 = time.monotonic()

            def at_30_v():
                ff.publish(Float64(data=30.0))
                fb.publish(Float64(data=0.0))
                sent = [v for t, ch, _, v in list(mdt.command_log) if t > t0 and ch == 'x']
                return sent and abs(sent[-1] - 30.0) < 1e-6
            assert probe.until(at_30_v, 10.0), mdt.command_log[-5:]
            proc.stdout.close()                 # the launcher and its pipe are gone
            proc.terminate()
            assert proc.wait(timeout=BOUND_S) == 0, (tmp_path / 'stderr.log').read_text()
        finally:
            if probe is not None:
                probe.close()
            procs.stop(proc)
        assert abs(mdt.command_log[-1][3]) < 1e-9, mdt.command_log[-5:]
        assert 'Traceback' not in (tmp_path / 'stderr.log').read_text()
