# SPDX-License-Identifier: Apache-2.0
"""
``bringup``'s own ROS side: it watches the graph and calls its services.

It publishes nothing on the control topics: the setpoint source of a scenario is the
``scenario_runner`` node (or the ``alignment_sequencer``), the same node ``ros2 launch``
starts. The observer records the trace of the run from ``displacement`` (every sample:
reliable, deep, transient local), the scenario's reference at each sample time (the
same :class:`~fiber_align.nodes.scenario_runner.Source` the runner publishes) or, with
no scenario, the graph's ``reference``, and ``drive_voltage``, ``optical_power`` and
``alignment_state``. Service clients live on a second node that only the calling thread
spins, so a call never waits on the executor thread.
"""

import json
import math
import threading
import time

import numpy as np

from fiber_align.nodes._common import CONTROL_QOS, stamp_ns


class BringupError(RuntimeError):
    """The graph could not be brought up or failed while running."""


class BadInput(BringupError):
    """A node refused its parameters (exit code 2): bringup exits 2 with its line."""


class StartStall(BringupError):
    """A lockstep graph did not answer its first sample within the start-up bound."""


class Runner:
    """
    Watch a running graph: trace, stall checks, service calls.

    :param source: the scenario's :class:`~fiber_align.nodes.scenario_runner.Source`
        (its values are the trace's ``r``), or ``None`` to record the graph's
        ``reference``.
    """

    def __init__(self, namespace, source, lockstep, rate_hz, duration_s=math.inf):
        """Create the nodes, their clients and subscriptions."""
        from lifecycle_msgs.srv import ChangeState, GetState
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64, String
        from std_srvs.srv import SetBool, Trigger
        ns = namespace.strip('/') or None
        self.node = Node('bringup', namespace=ns)
        self.cnode = Node('bringup_client', namespace=ns)
        self.cexec = SingleThreadedExecutor()
        self.cexec.add_node(self.cnode)
        self.ns = self.node.get_namespace().rstrip('/')
        self.source = source
        self.lockstep = lockstep
        self.period = 1.0 / rate_hz
        self.duration = float(duration_s)
        self.node.create_subscription(JointState, 'displacement', self._on_disp, CONTROL_QOS)
        self.node.create_subscription(Float64, 'drive_voltage', self._on_drive, CONTROL_QOS)
        if source is None:
            state_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                   reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.node.create_subscription(Float64, 'reference', self._on_reference,
                                          CONTROL_QOS)
            self.node.create_subscription(Float64, 'optical_power', self._on_power,
                                          CONTROL_QOS)
            self.node.create_subscription(String, 'alignment_state', self._on_state,
                                          state_qos)
        c = self.cnode
        self.change = c.create_client(ChangeState, 'actuator_driver/change_state')
        self.get_state = c.create_client(GetState, 'actuator_driver/get_state')
        self.run_cli = c.create_client(SetBool, 'simulated_actuator/run')
        self.align_cli = c.create_client(Trigger, 'align')
        self.switch_cli = c.create_client(SetBool, 'switch')
        self.active = False          # record samples
        self.t0_ns = None
        self.done = threading.Event()
        self.t, self.r, self.y, self.v, self.p = [], [], [], [], []
        self.states = []             # (sample index, status dict) of alignment_state
        self.progress = time.monotonic()   # wall time of the latest recorded sample
        self.stall_s = 10.0
        self.start_stall_s = 3.0
        self.started = time.monotonic()
        self.lock = threading.Lock()

    @property
    def samples(self):
        """Return the number of displacement samples recorded so far."""
        return len(self.y)

    def _on_disp(self, msg):
        if not self.active or self.done.is_set():
            return
        ns = stamp_ns(msg.header.stamp)
        if self.t0_ns is None:
            self.t0_ns = ns
        t = (ns - self.t0_ns) * 1e-9
        if self.lockstep:
            t = round(t / self.period) * self.period
        if t >= self.duration - 0.5 * self.period:
            self.done.set()
            return
        y = msg.position[0] if len(msg.position) else math.nan
        self.progress = time.monotonic()
        with self.lock:
            self.t.append(t)
            self.y.append(y)
            if self.source is not None:
                self.r.append(math.nan if self.source.open_loop else self.source.value(t))

    def _on_drive(self, msg):
        if self.active or self.v:
            with self.lock:
                self.v.append(msg.data)

    def _on_reference(self, msg):
        if self.active:
            with self.lock:
                self.r.append(msg.data)

    def _on_power(self, msg):
        if self.active:
            with self.lock:
                self.p.append(msg.data)

    def _on_state(self, msg):
        try:
            st = json.loads(msg.data)
        except ValueError:
            st = {'state': msg.data}
        with self.lock:
            self.states.append((self._state_index(st), st))

    def _state_index(self, st):
        """
        Return the sample index from which state ``st`` holds.

        Lockstep: the sample after the one the sequencer stepped last (its stamp in
        ``sample_time_s``); this observer may be seconds behind the graph there. Realtime:
        the number of samples received so far.
        """
        ts = st.get('sample_time_s')
        if self.lockstep and ts is not None and self.t0_ns is not None:
            return int(round((float(ts) - self.t0_ns * 1e-9) / self.period)) + 1
        return len(self.y)

    def event(self, n_before, timeout_s=5.0):
        """
        Return the sample index of the first state published after ``n_before`` states.

        A service answer of the sequencer publishes its new state first; this waits for it
        (bounded, s) and falls back to :meth:`samples` when none came.
        """
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self.lock:
                if len(self.states) > n_before:
                    return self.states[n_before][0]
            time.sleep(0.002)
        return self.samples

    def state(self):
        """Return the latest ``alignment_state`` status dict (``{}`` before the first)."""
        with self.lock:
            return dict(self.states[-1][1]) if self.states else {}

    def call(self, client, request, timeout, alive=lambda: None):
        """Call a service with a bounded wait (s); ``alive()`` may raise meanwhile."""
        end = time.monotonic() + timeout
        while not client.wait_for_service(timeout_sec=0.1):
            alive()
            if time.monotonic() > end:
                raise BringupError('service %s not available within %g s'
                                   % (client.srv_name, timeout))
        fut = client.call_async(request)
        while not fut.done() and time.monotonic() < end:
            self.cexec.spin_until_future_complete(fut, timeout_sec=0.1)
            alive()             # a server process that died answers nothing
        if not fut.done():
            client.remove_pending_request(fut)
            raise BringupError('service %s did not answer within %g s'
                               % (client.srv_name, timeout))
        return fut.result()

    def wait_nodes(self, names, timeout, alive=lambda: None):
        """Wait until every node in ``names`` is on the graph (bounded, s)."""
        end = time.monotonic() + timeout
        want = {(n, self.ns or '/') for n in names}
        while True:
            alive()
            have = set(self.node.get_node_names_and_namespaces())
            if want <= have:
                return
            if time.monotonic() > end:
                missing = sorted(n for n, _ in want - have)
                raise BringupError('nodes not up within %g s: %s' % (timeout, ', '.join(missing)))
            time.sleep(0.05)

    def count_nodes(self, name):
        """Return how many nodes called ``name`` are in this graph's namespace."""
        return sum(1 for n, ns in self.node.get_node_names_and_namespaces()
                   if n == name and ns == (self.ns or '/'))

    def activate_driver(self, timeout, alive=lambda: None):
        """Configure and activate the driver through lifecycle_msgs/srv/ChangeState."""
        from lifecycle_msgs.msg import State, Transition
        from lifecycle_msgs.srv import ChangeState, GetState
        for tid, label in ((Transition.TRANSITION_CONFIGURE, 'configure'),
                           (Transition.TRANSITION_ACTIVATE, 'activate')):
            req = ChangeState.Request()
            req.transition.id = tid
            if not self.call(self.change, req, timeout, alive).success:
                raise BringupError('actuator_driver refused to %s' % label)
        st = self.call(self.get_state, GetState.Request(), timeout)
        if st.current_state.id != State.PRIMARY_STATE_ACTIVE:
            raise BringupError('actuator_driver is %s, not active' % st.current_state.label)

    def endpoint_counts(self, topic):
        """Return ``(publishers, subscribers)`` of ``topic`` on the graph."""
        name = self.node.resolve_topic_name(topic)
        return self.node.count_publishers(name), self.node.count_subscribers(name)

    def wait_matched(self, topics, timeout, alive=lambda: None):
        """Wait until each topic has at least ``(publishers, subscribers)`` (bounded, s)."""
        end = time.monotonic() + timeout
        while True:
            alive()
            short = []
            for topic, (np_, ns_) in topics.items():
                have = self.endpoint_counts(topic)
                if have[0] < np_ or have[1] < ns_:
                    short.append('%s (%d/%d publishers, %d/%d subscribers)'
                                 % (topic, have[0], np_, have[1], ns_))
            if not short:
                return
            if time.monotonic() > end:
                raise BringupError('topics not connected within %g s: %s'
                                   % (timeout, ', '.join(short)))
            time.sleep(0.05)

    def foreign_publishers(self, topics):
        """Return the topics that have more publishers than ``topics`` allows (exactly)."""
        out = []
        for topic, (np_, _) in topics.items():
            n = self.endpoint_counts(topic)[0]
            if np_ and n > np_:
                out.append('%s (%d publishers, expected %d)' % (topic, n, np_))
        return out

    def set_running(self, on, timeout=5.0):
        """Start (True) or hold (False) the plant's sample clock."""
        from std_srvs.srv import SetBool
        return self.call(self.run_cli, SetBool.Request(data=bool(on)), timeout)

    def start(self):
        """Mark the start of the run (the stall clocks start now)."""
        self.active = True
        self.progress = self.started = time.monotonic()

    def check_stall(self):
        """
        Raise when the graph stopped answering.

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

    def wait_samples(self, n, wall_limit_s, alive=lambda: None, stop=None):
        """Wait until ``n`` samples are recorded or ``stop()`` is true; bounded (s wall)."""
        end = time.monotonic() + wall_limit_s
        while self.samples < n:
            alive()
            self.check_stall()
            if stop is not None and stop():
                return
            if time.monotonic() > end:
                raise BringupError('the scenario did not reach sample %d within %g s (at %d)'
                                   % (n, wall_limit_s, self.samples))
            time.sleep(0.002)

    def trace(self):
        """Return ``(t, r, y)`` arrays (s, m, m) of the samples seen (r NaN if unknown)."""
        with self.lock:
            n = len(self.t)
            r = np.full(n, np.nan)
            m = min(n, len(self.r))
            r[:m] = self.r[:m]
            return np.array(self.t), r, np.array(self.y)

    def series(self, name):
        """Return the per-sample series ``v`` (V) or ``p`` (W) padded with NaN."""
        with self.lock:
            n = len(self.t)
            out = np.full(n, np.nan)
            src = getattr(self, name)
            m = min(n, len(src))
            out[:m] = src[:m]
            return out

    def destroy(self):
        """Destroy both nodes."""
        self.cexec.shutdown(timeout_sec=0.5)
        self.cnode.destroy_node()
        self.node.destroy_node()
