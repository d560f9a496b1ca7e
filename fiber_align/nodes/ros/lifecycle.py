# SPDX-License-Identifier: Apache-2.0
"""
The lifecycle services of the managed nodes, on both sides.

Their ``~/change_state`` guard (:func:`guard_change_state`) and the manager's bounded
call of their services (:func:`call_bounded`).
"""

import threading
import time


def guard_change_state(node):
    """
    Make a lifecycle node's ``~/change_state`` refuse a transition its state does not offer.

    rclpy's handler (``LifecycleNodeMixin.__on_change_state`` -> ``__change_state``) hands
    the requested id straight to ``trigger_transition_by_id``, which raises ``RCLError``
    ("Transition is not registered") for an id that does not start from the current
    state, e.g. ``configure`` (1) while active; the exception leaves the service callback,
    the executor re-raises it and the process dies. This wraps the service's callback
    (the executors call ``Service.callback``): an unavailable id or label is answered with
    ``success`` false, a WARN in the log and on ``/diagnostics`` (``node.health``) and a
    count in ``node.refused_transitions``; an available one goes to rclpy unchanged.
    """
    srv = getattr(node, '_service_change_state', None)
    node.refused_transitions = 0
    if srv is None:
        return
    inner = srv.callback

    def change_state(request, response):
        t = request.transition
        try:
            state = node._state_machine.current_state[1]
            offered = [(i, lbl) for i, lbl, *_ in node._state_machine.available_transitions]
            ok = any((lbl == t.label) if t.label else (i == t.id) for i, lbl in offered)
            if ok:
                return inner(request, response)
            why = ('refused lifecycle transition %s: not available in state %s '
                   '(available: %s)' % (repr(t.label) if t.label else 'id %d' % t.id,
                                        state, ', '.join('%s (%d)' % (lbl, i)
                                                         for i, lbl in offered)))
        except Exception as exc:  # noqa: BLE001 - no request may kill the node
            why = 'lifecycle transition %d %r failed: %s' % (t.id, t.label, exc)
        node.refused_transitions += 1
        node.get_logger().warning(why)
        node.health.set_values(refused_transitions=node.refused_transitions)
        node.health.warn(why)
        response.success = False
        return response

    srv.callback = change_state


def call_bounded(client, request, timeout_s, alive, resend_s=None, slice_s=0.1):
    """
    Call a service with a bounded wait; return the response or the reason (str).

    :param client: the rclpy service client; :param timeout_s: the bound (s).
    :param alive: ``() -> bool``, False once the context shuts down (the wait ends).
    :param resend_s: for a query (``get_state``): send the request again when no answer
        came within this many seconds (a server may drop its response while the
        discovery of this client is still under way); the first answer of any counts.
    :param slice_s: the wait's slice (s).
    """
    done = threading.Event()
    end = time.monotonic() + float(timeout_s)
    futs, sent = [], 0.0
    while not futs or not done.wait(slice_s):
        now = time.monotonic()
        if futs and (now >= end or not alive()):
            for f in futs:
                client.remove_pending_request(f)
            return 'no answer from %s within %g s' % (client.srv_name, timeout_s)
        if not futs or (resend_s is not None and now - sent >= resend_s):
            fut = client.call_async(request)
            fut.add_done_callback(lambda f: done.set())
            futs.append(fut)
            sent = now
    fut = next(f for f in futs if f.done())
    for f in futs:
        if f is not fut and not f.done():
            client.remove_pending_request(f)
    exc = fut.exception()
    if exc is not None:
        return '%s failed: %s' % (client.srv_name, exc)
    return fut.result()
