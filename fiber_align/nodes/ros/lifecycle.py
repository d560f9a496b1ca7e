# SPDX-License-Identifier: Apache-2.0
"""The lifecycle ``~/change_state`` guard of the managed (lifecycle) nodes."""


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
