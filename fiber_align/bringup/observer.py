# SPDX-License-Identifier: Apache-2.0
"""
``bringup``'s one observer of a running graph (the 1-D graph, the rig, the bench).

It publishes nothing on the control topics; it records its streams (every sample), the
``alignment_state`` changes (a :class:`~fiber_align.analysis.run_record.RunRecord`) and
``/diagnostics`` (a thread of its own), in an rclpy context of its own; its service
clients live on a second node only the calling thread spins.
"""

import math
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor

from fiber_align.analysis.run_record import DiagnosticsRecord, RunRecord
from fiber_align.control.trajectory import stamp_ns
from fiber_align.nodes.ros.qos import DIAG_QOS, LATCHED_QOS, sample_pub_qos, STATE_QOS

#: s (wall) an alignment's end state may arrive after its bound in samples has passed
STATE_GRACE_S = 2.0
#: s (wall): a service call's bound (bringup's ``service_timeout_s``); unanswered for
#: ``RESEND_S``, a request is sent again (a loaded machine loses answers: docs/ros_interface.md)
CALL_S, RESEND_S = 30.0, 2.0


class BringupError(RuntimeError):
    """The graph could not be brought up or failed while running."""


class BadInput(BringupError):
    """A node refused its parameters (exit code 2): bringup exits 2 with its line."""


class Refused(BringupError):
    """The sequencer refused a command (its answer's ``success`` false)."""


class StartStall(BringupError):
    """A lockstep graph did not answer its first sample within the start-up bound."""


def spin_thread(executor):
    """Return a started daemon thread spinning ``executor`` until it is shut down."""
    def spin():
        try:
            executor.spin()
        except Exception:  # noqa: BLE001 - executor shut down at exit
            pass
    th = threading.Thread(target=spin, daemon=True)
    th.start()
    return th


class DiagnosticsWatch(DiagnosticsRecord):
    """The ``/diagnostics`` of a run, on a node and thread of its own (fresh at the stop)."""

    def __init__(self, namespace, context):
        """Subscribe and start spinning (``namespace``: the graph's, or ``''``)."""
        import rclpy
        super().__init__()
        self.node = rclpy.create_node('bringup_diagnostics', namespace=namespace or None,
                                      context=context)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', lambda msg: [
            self.add(st, time.monotonic()) for st in msg.status], DIAG_QOS)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.thread = spin_thread(self.executor)

    def close(self):
        """Stop the executor and join the thread (it must leave rclpy before exit)."""
        self.executor.shutdown(timeout_sec=0.5)
        self.thread.join(timeout=2.0)
        self.node.destroy_node()


class Observer(RunRecord):
    """
    Watch a running graph: streams, states, diagnostics, stall checks, service calls.

    :param namespace: the graph's (``''``: none). :param streams: key -> topic recorded
        per message (``*displacement``: its position, m; else ``Float64`` data, SI).
    :param clock, source, lockstep, rate_hz, duration_s: the record's (``RunRecord``).
    :param qos: the streams' QoS (``None``: the sync mode's per-sample profile).
    """

    def __init__(self, namespace, streams, clock=None, source=None, lockstep=False,
                 rate_hz=1000.0, duration_s=math.inf, qos=None):
        """Create the context, both nodes, their subscriptions and the spin threads."""
        import rclpy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64, String
        super().__init__(streams, clock, source, lockstep, rate_hz, duration_s)
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, args=[])
        ns = namespace.strip('/') or None
        self.node = rclpy.create_node('bringup', namespace=ns, context=self.ctx)
        # spun only while a call of bringup's waits: parameter services there would go
        # unanswered, and `ros2 param list` waits on every node that offers them
        self.cnode = rclpy.create_node('bringup_client', namespace=ns, context=self.ctx,
                                       start_parameter_services=False)
        self.cexec = SingleThreadedExecutor(context=self.ctx)
        self.cexec.add_node(self.cnode)
        self.stall_s, self.start_stall_s = 10.0, 3.0
        qos = sample_pub_qos(lockstep) if qos is None else qos
        for key, topic in streams.items():
            typ = JointState if topic.endswith('displacement') else Float64
            self.node.create_subscription(typ, topic, self._adder(key), qos)
        self.node.create_subscription(String, 'alignment_state',
                                      lambda m: self.add_state(m.data), STATE_QOS)
        self.node.create_subscription(String, 'scenario_state',
                                      lambda m: self.runner_state(m.data), LATCHED_QOS)
        self.clients, self.call_s = {}, CALL_S
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.spin = spin_thread(self.executor)
        self.watch = DiagnosticsWatch(namespace, self.ctx)

    def client(self, srv_type, name):
        """Return the (cached) client of service ``name`` (relative to the namespace)."""
        if name not in self.clients:
            self.clients[name] = self.cnode.create_client(srv_type, name)
        return self.clients[name]

    def _adder(self, key):
        def add(msg):
            if not hasattr(msg, 'position'):
                return self.add(key, float(msg.data))
            self.add(key, float(msg.position[0]) if len(msg.position) else math.nan,
                     stamp_ns(msg.header.stamp) if key == self.clock else None)
        return add

    def call(self, client, request, timeout, alive=lambda: None, effect=None):
        """Call a service with a bounded wait (s); ``alive()`` may raise meanwhile."""
        return self.call_all([(client, request)], timeout, alive, effect)[0]

    def call_all(self, calls, timeout, alive=lambda: None, effect=None):
        """
        Send every ``(client, request)`` at once (plants held together); the answers.

        Unanswered for :data:`RESEND_S`: sent again, or, a command (``effect``), never sent
        twice but done (answer ``None``) once ``effect()`` is true.
        """
        end = time.monotonic() + timeout
        for client, _ in calls:
            while not client.wait_for_service(timeout_sec=0.1):
                alive()
                if time.monotonic() > end:
                    raise BringupError('service %s not available within %g s'
                                       % (client.srv_name, timeout))
        futs = [client.call_async(request) for client, request in calls]
        out = []
        for (client, request), fut in zip(calls, futs):
            sent = time.monotonic()
            while not fut.done() and time.monotonic() < end:
                self.cexec.spin_until_future_complete(fut, timeout_sec=0.1)
                alive()             # a server process that died answers nothing
                late = not fut.done() and time.monotonic() - sent > RESEND_S
                if late and effect is not None and effect():
                    break
                if late and effect is None:
                    client.remove_pending_request(fut)
                    fut, sent = client.call_async(request), time.monotonic()
            if fut.done():
                out.append(fut.result())
                continue
            client.remove_pending_request(fut)
            if effect is not None and effect():
                out.append(None)
                continue
            raise BringupError('service %s did not answer within %g s'
                               % (client.srv_name, timeout))
        return out

    def command(self, name, data=None, alive=lambda: None, timeout=None):
        """
        Call the sequencer's ``name`` (``data``: a SetBool, ``switch``; else a Trigger).

        Return the sample index of the state it caused. :raises Refused: not ``success``.
        """
        from std_srvs.srv import SetBool, Trigger
        srv, req = (Trigger, Trigger.Request()) if data is None else (
            SetBool, SetBool.Request(data=bool(data)))
        n = len(self.states)
        res = self.call(self.client(srv, name), req, timeout or self.call_s, alive,
                        effect=lambda: len(self.states) > n)
        if res is not None and not res.success:     # None: its answer lost, its state seen
            what = name if data is None else '%s %s' % (name, 'on' if data else 'off')
            raise Refused('%s refused: %s' % (what, res.message))
        return self.caused(n, name)

    def ended(self, what):
        """Return the error of ``what`` (``alignment``, ...) that ended short of its state."""
        st = self.status
        return BringupError('%s ended in %s: %s'
                            % (what, st.get('state'), st.get('fault_reason') or 'timeout'))

    def align(self, alive, clock, max_samples, wall_s=120.0):
        """
        Call ``align``, wait for TRACKING; return ``(align sample, its sample, status)``.

        ``(align sample, None, None)``: it ended otherwise (:meth:`ended`). ``clock()``:
        the samples so far (``max_samples`` bounds them; ``wall_s``, s, the wall time).
        """
        k_align = self.command('align', alive=alive)
        k_max, over = clock() + max_samples, []

        def ended():
            if self.status.get('state') in ('TRACKING', 'FAULT'):
                return True
            # past the bound in samples: the status may still be on its way (two lockstep
            # graphs on two cores: 1,000 samples ran ahead of a TRACKING at sample 134)
            if clock() > k_max and not over:
                over.append(time.monotonic())
            return bool(over) and time.monotonic() - over[0] > STATE_GRACE_S
        self.wait(ended, wall_s, alive, 'TRACKING')
        return (k_align,) + self.first('TRACKING', k_align)

    def set_text(self, node, name, value, alive=lambda: None, timeout=None):
        """Set the text parameter ``name`` of ``node`` (relative), as ``ros2 param set``."""
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters
        req = SetParameters.Request(parameters=[Parameter(name=name, value=ParameterValue(
            type=ParameterType.PARAMETER_STRING, string_value=str(value)))])
        res = self.call(self.client(SetParameters, node + '/set_parameters'), req,
                        timeout or self.call_s, alive)
        if not res.results or not res.results[0].successful:
            raise Refused('%s %s=%r refused: %s' % (node, name, value, res.results[0].reason
                                                    if res.results else 'no answer'))

    def wait(self, cond, timeout, alive, what):
        """Wait (bounded, s wall) until ``cond()``; ``alive()`` may raise meanwhile."""
        end = time.monotonic() + timeout
        while not cond():
            alive()
            if time.monotonic() > end:
                raise BringupError('%s not reached within %g s (at sample %d; %s)'
                                   % (what, timeout, self.samples, self.status or '-'))
            time.sleep(0.005)

    def node_names(self):
        """Return the (name, namespace) pairs of every node on the graph."""
        return set(self.node.get_node_names_and_namespaces())

    def active_nodes(self, names, alive):
        """Return True when every lifecycle node in ``names`` (relative) is active."""
        from lifecycle_msgs.msg import State
        from lifecycle_msgs.srv import GetState
        return all(self.call(self.client(GetState, n + '/get_state'), GetState.Request(),
                             5.0, alive).current_state.id == State.PRIMARY_STATE_ACTIVE
                   for n in names)

    def endpoint_counts(self, topics):
        """Return ``{topic: (publishers, subscribers)}`` of ``topics`` on the graph."""
        full = {t: self.node.resolve_topic_name(t) for t in topics}
        return {t: (self.node.count_publishers(n), self.node.count_subscribers(n))
                for t, n in full.items()}

    def start(self):
        """Mark the start of the run (recording and the stall clocks start now)."""
        self.active = True
        self.progress = self.started = time.monotonic()
        self.watch.run_from = self.started

    def check_stall(self):
        """
        Raise when the graph stopped answering (the clock stream only).

        :raises StartStall: lockstep, the first sample not answered within
            ``start_stall_s`` (s wall).
        :raises BringupError: no sample for ``stall_s`` (s wall).
        """
        now = time.monotonic()
        if self.lockstep and self.samples < 2 and not self.done.is_set() and \
                now - self.started > self.start_stall_s:
            raise StartStall('the first sample was not answered within %g s'
                             % self.start_stall_s)
        quiet = now - self.progress
        if quiet > self.stall_s and not self.done.is_set():
            raise BringupError('the graph stalled at sample %d: no displacement for %.1f s'
                               % (self.samples, quiet))

    def wait_samples(self, n, wall_limit_s, alive=lambda: None, stop=lambda: False):
        """Wait until ``n`` samples are recorded or ``stop()`` is true; bounded (s wall)."""
        def check():
            alive()
            self.check_stall()
        self.wait(lambda: self.samples >= n or stop(), wall_limit_s, check, 'sample %d' % n)

    def destroy(self):
        """Stop the threads, destroy the nodes, shut the context down."""
        import rclpy
        self.executor.shutdown(timeout_sec=0.5)
        self.spin.join(timeout=2.0)
        self.watch.close()
        self.cexec.shutdown(timeout_sec=0.5)
        self.cnode.destroy_node()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
