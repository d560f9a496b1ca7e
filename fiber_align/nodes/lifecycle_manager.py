# SPDX-License-Identifier: Apache-2.0
"""
``lifecycle_manager``: bring the graph's managed (lifecycle) nodes to active, in order.

The stand-in for nav2's ``lifecycle_manager``, which a pip install of ROS 2 lacks, with
its parameter names (swap it for nav2's where that is installed); any process may host
the managed nodes. Parameters (defaults in ``config/lifecycle_manager.yaml``; the graph
descriptions set ``node_names``): ``node_names`` and ``autostart`` as nav2's (activated in
this order, deactivated in the reverse), ``service_timeout_s`` (s: the bound on each
wait for services and on each call), ``diagnostics_period_s``. ``managed_nodes``, the
old name of ``node_names``, still works: set, it wins, with one deprecation WARN.

Services (std_srvs/Trigger): ``~/startup`` (configure what is unconfigured, activate
what is inactive) and ``~/shutdown`` (deactivate, clean up: the nodes end
unconfigured); each answers ``success`` and one line. Progress and failures go to the
log and ``/diagnostics`` (ERROR with the reason; ``state.<node>``: each node's last
known state). A failure stops the sequence at that node, never the manager.
"""

import sys
import threading
import time

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from fiber_align.graph.ranges import MANAGER_RANGES
from fiber_align.graph.registry import NODES
from fiber_align.nodes.ros.diagnostics import ERROR, Health, OK
from fiber_align.nodes.ros.lifecycle import call_bounded
from fiber_align.nodes.ros.params import (
    declare, declare_graph_values, declare_row, descriptor, node_defaults)
from fiber_align.nodes.ros.runtime import run_node

#: the registry's entry of this node: its name and params files
SPEC = NODES['lifecycle_manager']
#: The alias of ``node_names`` this node took before (deprecated: one WARN when set).
DEPRECATED_NAMES = 'managed_nodes'
#: lifecycle_msgs State ids and Transition ids used here (lifecycle_msgs/msg/*).
UNCONFIGURED, INACTIVE, ACTIVE, FINALIZED = 1, 2, 3, 4
CONFIGURE, CLEANUP, ACTIVATE, DEACTIVATE = 1, 2, 3, 4
#: Slice (s) of the bounded waits; a ``get_state`` unanswered this long (s) is resent.
WAIT_SLICE_S, GET_STATE_RESEND_S = 0.1, 1.0


class LifecycleManager(Node):
    """Configure and activate the managed nodes; report on ``/diagnostics``."""

    def __init__(self, **kwargs):
        """Declare the parameters (defaults from config/), create the services."""
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        declare(self, d, 'node_names', 'lifecycle nodes to configure and activate, in '
                'order (relative or absolute names; as nav2_lifecycle_manager)',
                read_only=True)
        declare(self, d, 'autostart', 'run the start-up sequence at once', read_only=True)
        declare_row(self, d, MANAGER_RANGES, 'service_timeout_s', False)
        declare_graph_values(self, d, 'diagnostics_period_s')
        self.managed = self._node_names()
        self.states = {n: 'unknown' for n in self.managed}
        self._busy = threading.Lock()
        self._lc_group = ReentrantCallbackGroup()
        self._lc_clients = {}
        self.health = Health(self, self.get_parameter('diagnostics_period_s').value)
        self.health.summary(OK, 'waiting: %s' % (', '.join(self.managed) or 'no nodes'))
        self._update_values()
        group = MutuallyExclusiveCallbackGroup()
        self.create_service(Trigger, '~/startup', self._on_startup, callback_group=group)
        self.create_service(Trigger, '~/shutdown', self._on_shutdown, callback_group=group)
        if self.get_parameter('autostart').value:
            self._autostart_timer = self.create_timer(
                0.01, self._autostart, callback_group=MutuallyExclusiveCallbackGroup())

    def _node_names(self):
        """Return ``node_names``, or the deprecated alias (no default) when it is set."""
        self.declare_parameter(
            DEPRECATED_NAMES, Parameter.Type.STRING_ARRAY, descriptor(
                'deprecated: use node_names (same meaning)', read_only=True))
        old = self.get_parameter_or(DEPRECATED_NAMES, None)
        if old is not None and old.type_ == Parameter.Type.STRING_ARRAY:
            self.get_logger().warning(
                'parameter %s is deprecated: use node_names (as nav2_lifecycle_manager); '
                'using %s=%s' % (DEPRECATED_NAMES, DEPRECATED_NAMES, list(old.value)))
            return [str(n) for n in old.value]
        return [str(n) for n in self.get_parameter('node_names').value]

    # -- services -------------------------------------------------------------------
    def _autostart(self):
        self.destroy_timer(self._autostart_timer)
        self.startup()

    def _on_startup(self, request, response):
        response.success, response.message = self.startup()
        return response

    def _on_shutdown(self, request, response):
        response.success, response.message = self.shutdown()
        return response

    # -- sequences ------------------------------------------------------------------
    def startup(self):
        """Configure and activate every managed node in order; return (ok, message)."""
        return self._run('startup', self.managed, self._bring_up)

    def shutdown(self):
        """Deactivate and clean up every managed node in reverse order; (ok, message)."""
        return self._run('shutdown', list(reversed(self.managed)), self._bring_down)

    def _run(self, what, nodes, step):
        if not self._busy.acquire(blocking=False):
            return False, '%s refused: another sequence is running' % what
        try:
            t0 = time.monotonic()
            for name in nodes:
                why = step(name)
                if why:
                    msg = '%s failed at %s: %s' % (what, name, why)
                    self.get_logger().error(msg)
                    self.health.summary(ERROR, msg)
                    self.health.error(msg)
                    return False, msg
            final = 'active' if what == 'startup' else 'unconfigured'
            msg = '%s done in %.2f s: %s %s' % (what, time.monotonic() - t0,
                                                ', '.join(nodes) or 'no nodes', final)
            self.get_logger().info(msg)
            self.health.summary(OK, msg)
            self.health.publish()
            return True, msg
        except Exception as exc:  # noqa: BLE001 - the manager never dies of a node
            msg = '%s failed: %s: %s' % (what, type(exc).__name__, exc)
            self.get_logger().error(msg)
            self.health.summary(ERROR, msg)
            return False, msg
        finally:
            self._busy.release()

    def _bring_up(self, name):
        """Return ``None`` once ``name`` is active, else the reason (str)."""
        return self._walk(name, {UNCONFIGURED: CONFIGURE, INACTIVE: ACTIVATE}, ACTIVE)

    def _bring_down(self, name):
        """Return ``None`` once ``name`` is unconfigured, else the reason (str)."""
        return self._walk(name, {ACTIVE: DEACTIVATE, INACTIVE: CLEANUP}, UNCONFIGURED)

    def _walk(self, name, steps, goal):
        """Apply ``steps`` (state id -> transition id) until ``goal``; ``None`` or why."""
        labels = {CONFIGURE: 'configure', CLEANUP: 'cleanup', ACTIVATE: 'activate',
                  DEACTIVATE: 'deactivate'}
        why = self._wait_services(name)
        if why:
            return why
        for _ in range(len(steps) + 4):      # transition states may need a second look
            state = self._get_state(name)
            if isinstance(state, str):
                return state
            sid, label = state
            self._set_state(name, label)
            if sid == goal:
                return None
            if sid == FINALIZED:
                return 'node is finalized (shut down): restart it'
            if sid not in steps:             # a transition state: look again shortly
                time.sleep(0.05)
                continue
            tid = steps[sid]
            self.health.summary(OK, '%s: %s (%s)' % (name, labels[tid], label))
            self.get_logger().info('%s: %s' % (name, labels[tid]))
            ok = self._change_state(name, tid)
            if isinstance(ok, str):
                return ok
            if not ok:
                state = self._get_state(name)
                self._set_state(name, state[1] if isinstance(state, tuple) else 'unknown')
                return 'transition %s refused (state now %s)' % (labels[tid],
                                                                 self.states[name])
        return 'state did not settle'

    # -- service calls --------------------------------------------------------------
    def _client(self, name, srv):
        from lifecycle_msgs.srv import ChangeState, GetState
        if (name, srv) not in self._lc_clients:
            self._lc_clients[name, srv] = self.create_client(
                GetState if srv == 'get_state' else ChangeState, '%s/%s' % (name, srv),
                callback_group=self._lc_group)
        return self._lc_clients[name, srv]

    def _timeout(self):
        return float(self.get_parameter('service_timeout_s').value)

    def _wait_services(self, name):
        """Wait (bounded, retrying) for the node's lifecycle services; ``None`` or why."""
        timeout = self._timeout()
        end = time.monotonic() + timeout
        tries = 0
        for srv in ('get_state', 'change_state'):
            cl = self._client(name, srv)
            while not cl.wait_for_service(timeout_sec=min(1.0, max(0.0,
                                                                   end - time.monotonic()))):
                tries += 1
                if time.monotonic() >= end or not self.context.ok():
                    return 'no %s service within %g s (%s)' % (
                        srv, timeout, self.resolve_service_name(cl.srv_name))
                if tries % 5 == 0:
                    self.get_logger().info('waiting for %s/%s' % (name, srv))
                    self.health.summary(OK, 'waiting for %s/%s' % (name, srv))
        return None

    def _call(self, name, srv, request, resend_s=None):
        """Call a service (bounded, :func:`call_bounded`); the response or why (str)."""
        return call_bounded(self._client(name, srv), request, self._timeout(),
                            self.context.ok, resend_s, WAIT_SLICE_S)

    def _get_state(self, name):
        from lifecycle_msgs.srv import GetState
        res = self._call(name, 'get_state', GetState.Request(), resend_s=GET_STATE_RESEND_S)
        return res if isinstance(res, str) else (res.current_state.id, res.current_state.label)

    def _change_state(self, name, transition_id):
        from lifecycle_msgs.srv import ChangeState
        req = ChangeState.Request()
        req.transition.id = int(transition_id)
        res = self._call(name, 'change_state', req)
        return res if isinstance(res, str) else bool(res.success)

    def _set_state(self, name, label):
        self.states[name] = label
        self._update_values()

    def _update_values(self):
        self.health.set_values(**{'state.%s' % n: s for n, s in self.states.items()})


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(LifecycleManager, SPEC.node, args, realtime=lambda node: False,
                    threads=3)


if __name__ == '__main__':
    sys.exit(main())
