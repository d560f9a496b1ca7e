# SPDX-License-Identifier: Apache-2.0
"""bringup's observer on a graph: the nodes it adds answer, every state change reaches it."""

import time

import pytest

from fiber_align.bringup.observer import Observer


@pytest.mark.ros  # starts rclpy
def test_every_node_of_bringup_that_offers_parameters_answers_them():
    # `ros2 param list` asks every node that offers list_parameters and waits for each:
    # a node of bringup's that offers the service but is spun only during its own calls
    # (the service client) held the CLI for ever
    import rclpy
    from rcl_interfaces.srv import ListParameters
    from rclpy.executors import SingleThreadedExecutor
    obs = Observer('obsparams', {'y': 'displacement'})
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=[])
    probe = rclpy.create_node('probe', context=ctx, start_parameter_services=False)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(probe)
    try:
        want = {'/obsparams/bringup', '/obsparams/bringup_client'}
        end = time.monotonic() + 10.0
        while time.monotonic() < end and not want <= {
                '%s/%s' % (ns.rstrip('/'), n) for n, ns in probe.get_node_names_and_namespaces()}:
            time.sleep(0.05)
        names = probe.get_node_names_and_namespaces()
        offered = [('%s/%s' % (ns.rstrip('/'), n)) for n, ns in names if ns.startswith(
            '/obsparams') and any(s == '%s/%s/list_parameters' % (ns.rstrip('/'), n)
                                  for s, _ in probe.get_service_names_and_types())]
        assert '/obsparams/bringup' in offered and '/obsparams/bringup_client' not in offered
        for name in offered:
            cli = probe.create_client(ListParameters, name + '/list_parameters')
            assert cli.wait_for_service(timeout_sec=5.0), name
            fut = cli.call_async(ListParameters.Request())
            ex.spin_until_future_complete(fut, timeout_sec=2.0)
            assert fut.done(), '%s offers list_parameters and does not answer' % name
    finally:
        ex.shutdown(timeout_sec=1.0)
        probe.destroy_node()
        rclpy.try_shutdown(context=ctx)
        obs.destroy()


@pytest.mark.ros  # starts rclpy
def test_every_alignment_state_change_reaches_bringup_in_a_burst():
    # SEARCHING and PEAKING one update apart reached a lagging depth-1 reader as one: the
    # lost SEARCHING put a lockstep array run's align one sample late (3 of 6 runs beside
    # three CPU hogs). 50 changes sent at once, every one is kept, in order.
    import json

    import rclpy
    from std_msgs.msg import String

    from fiber_align.nodes.ros.qos import STATE_QOS
    obs = Observer('obsstate', {})
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=[])
    node = rclpy.create_node('sequencer', namespace='obsstate', context=ctx)
    try:
        pub = node.create_publisher(String, 'alignment_state', STATE_QOS)
        end = time.monotonic() + 10.0
        while pub.get_subscription_count() < 1 and time.monotonic() < end:
            time.sleep(0.01)
        assert pub.get_subscription_count() == 1
        sent = [{'state': 'PEAKING' if i % 2 else 'SEARCHING', 'sample': i} for i in range(50)]
        for st in sent:
            pub.publish(String(data=json.dumps(st)))
        end = time.monotonic() + 5.0
        while len(obs.states) < len(sent) and time.monotonic() < end:
            time.sleep(0.01)
        assert [s for _, s in obs.states] == sent
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        obs.destroy()


@pytest.mark.ros  # starts rclpy
def test_the_plants_are_started_and_held_with_every_request_sent_before_any_answer():
    # one SetBool round trip per plant held a station's first plant while its others ran,
    # and that axis' driver tripped its watchdog: bringup sends every ~/run at once.
    # Four servers answer only once all four requests are in (a barrier): calls made one
    # after the other would each wait for an answer that never comes.
    import threading

    import rclpy
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.executors import MultiThreadedExecutor
    from std_srvs.srv import SetBool
    barrier = threading.Barrier(4, timeout=3.0)

    def answer(req, res):
        try:
            barrier.wait()
            res.success = True
        except threading.BrokenBarrierError:
            res.success = False
        return res
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=[])
    server = rclpy.create_node('plants', namespace='obsrun', context=ctx)
    group = ReentrantCallbackGroup()
    for k in range(4):
        server.create_service(SetBool, 'p%d/run' % k, answer, callback_group=group)
    ex = MultiThreadedExecutor(num_threads=5, context=ctx)
    ex.add_node(server)
    spin = threading.Thread(target=ex.spin, daemon=True)
    spin.start()
    obs = Observer('obsrun', {})
    try:
        calls = [(obs.client(SetBool, 'p%d/run' % k), SetBool.Request(data=False))
                 for k in range(4)]
        answers = obs.call_all(calls, 10.0)
        assert [a.success for a in answers] == [True] * 4
    finally:
        obs.destroy()
        ex.shutdown(timeout_sec=1.0)
        spin.join(timeout=2.0)
        server.destroy_node()
        rclpy.try_shutdown(context=ctx)


class _Future:
    def __init__(self, answer=None):
        self.answer = answer

    def done(self):
        return self.answer is not None

    def result(self):
        return self.answer


class _LosingClient:
    """A service whose first ``lost`` answers never come (a loaded machine's lost reply)."""

    srv_name = 'svc'

    def __init__(self, lost):
        self.lost, self.sent, self.dropped = lost, 0, 0

    def wait_for_service(self, timeout_sec=None):
        return True

    def call_async(self, request):
        self.sent += 1
        return _Future(None if self.sent <= self.lost else ('answer', self.sent))

    def remove_pending_request(self, fut):
        self.dropped += 1


class _Exec:
    def spin_until_future_complete(self, fut, timeout_sec=None):
        time.sleep(0.01)


@pytest.mark.ros  # imports rclpy
@pytest.mark.parametrize('lost', [1, 2])
def test_a_lost_answer_is_asked_again_after_the_resend_time(monkeypatch, lost):
    # a plant's run, a parameter: the same request again does the same
    from fiber_align.bringup import observer
    monkeypatch.setattr(observer, 'RESEND_S', 0.05)
    obs, cli = type('O', (), {'cexec': _Exec()})(), _LosingClient(lost)
    assert observer.Observer.call_all(obs, [(cli, 'req')], 5.0) == [('answer', lost + 1)]
    assert cli.dropped == lost


@pytest.mark.ros  # imports rclpy
def test_a_command_whose_answer_is_lost_is_done_once_its_effect_is_seen(monkeypatch):
    # align ran (its state came) and its answer never did: never sent twice
    from fiber_align.bringup import observer
    monkeypatch.setattr(observer, 'RESEND_S', 0.05)
    obs, cli = type('O', (), {'cexec': _Exec()})(), _LosingClient(10)
    seen = []
    t0 = time.monotonic()
    assert observer.Observer.call_all(obs, [(cli, 'req')], 5.0,
                                      effect=lambda: bool(seen) or seen.append(1)) == [None]
    assert cli.sent == 1 and time.monotonic() - t0 < 1.0
    # nothing seen: the bounded wait ends in the error, still one request
    cli = _LosingClient(10)
    with pytest.raises(observer.BringupError, match='did not answer within 0.3 s'):
        observer.Observer.call_all(obs, [(cli, 'req')], 0.3, effect=lambda: False)
    assert cli.sent == 1
