# SPDX-License-Identifier: Apache-2.0
"""
One graph path: ``ros2 launch`` and ``bringup`` start the same graph with the same params.

The same configuration (namespace ``paths``, controller ``pid``, the default composed
layout, no scenario) is started once through ``ros2 launch fiber_align
fiber_align.launch.py`` (the colcon build of the package, the upstream CLI of the venv)
and once through ``bringup``; every node of the description is asked for every parameter
(``rcl_interfaces`` ``ListParameters`` and ``GetParameters``, what ``ros2 param dump``
calls): the two runs must be identical. Each run is bounded and its processes are
stopped by pid (and process group) even on failure.
"""

import os
import signal
import subprocess
import sys
import time

import pytest

from fiber_align.graph import description as graph
import test_ros2_cli
from test_ros2_cli import descendants, kill_group, spawn, stop_launch

ros2_env = test_ros2_cli.ros2_env   # the colcon-built package and the ros2 CLI

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NAMESPACE = 'paths'
UP_WITHIN_S = 60.0
#: s: a service request without an answer this long is sent again
RESEND_S = 2.0


def dump(nodes, within_s=UP_WITHIN_S):
    """Return ``{node: {parameter: value}}`` of every node (relative to the namespace)."""
    import rclpy
    from rcl_interfaces.srv import GetParameters, ListParameters
    from rclpy.parameter import parameter_value_to_python
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=[])
    from rclpy.executors import SingleThreadedExecutor
    node = rclpy.create_node('graph_paths_probe', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    end = time.monotonic() + within_s
    out = {}
    try:
        for n in nodes:
            full = '/%s/%s' % (NAMESPACE, n)

            def call(srv, name, req):
                cli = node.create_client(srv, '%s/%s' % (full, name))
                while not cli.wait_for_service(timeout_sec=0.2):
                    assert time.monotonic() < end, '%s/%s not up in time' % (full, name)
                # asked again after RESEND_S without an answer: a server may drop its
                # response while its discovery of this client is still under way
                while True:
                    fut = cli.call_async(req)
                    ex.spin_until_future_complete(
                        fut, timeout_sec=max(0.1, min(RESEND_S, end - time.monotonic())))
                    if fut.done() or time.monotonic() >= end:
                        break
                    cli.remove_pending_request(fut)
                assert fut.done(), '%s/%s did not answer' % (full, name)
                return fut.result()
            names = sorted(call(ListParameters, 'list_parameters',
                                ListParameters.Request()).result.names)
            values = call(GetParameters, 'get_parameters',
                          GetParameters.Request(names=names)).values
            out[n] = {k: parameter_value_to_python(v) for k, v in zip(names, values)}
    finally:
        ex.shutdown(timeout_sec=0.5)
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return out


def _stop_bringup(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            pass
    kill_group(proc)


def test_launch_and_bringup_give_every_node_the_same_parameters(ros2_env, tmp_path):
    g = graph.build(namespace=NAMESPACE, controller='pid')
    nodes = [n for p in g.processes for n in p.nodes]
    assert 'lifecycle_manager' in nodes and 'actuator_driver' in nodes
    launch = spawn(ros2_env, ['ros2', 'launch', 'fiber_align', 'fiber_align.launch.py',
                              'namespace:=' + NAMESPACE, 'controller:=pid'],
                   tmp_path / 'launch.log')
    kids = []
    try:
        launched = dump(nodes)
        kids = descendants(launch.pid)
    finally:
        stop_launch(launch)
        for pid in kids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    env = dict(os.environ)
    with open(tmp_path / 'bringup.log', 'wb') as log:
        b = subprocess.Popen([sys.executable, '-m', 'fiber_align.bringup', '--namespace',
                              NAMESPACE, '--controller', 'pid', '--quiet'], env=env,
                             stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        brought = dump(nodes)
    finally:
        _stop_bringup(b)
    assert set(launched) == set(brought) == set(nodes)
    for n in nodes:
        assert launched[n] == brought[n], (n, {
            k: (launched[n].get(k), brought[n].get(k))
            for k in set(launched[n]) | set(brought[n])
            if launched[n].get(k) != brought[n].get(k)})
    assert launched['fuzzy_pid_controller']['controller'] == 'pid'
