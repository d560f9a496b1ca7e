# SPDX-License-Identifier: Apache-2.0
"""
A node's Health: the diagnostic_updater shape; the endpoint check runs in the slack.

The shape of ``diagnostic_updater.Updater`` (tasks, the status wrapper, ``summary``) so
the stand-in can be swapped for it; the endpoint check, a topic per job of the slack.
"""

from types import SimpleNamespace

from std_msgs.msg import Float64

from fiber_align.control.cycle import Slack
from fiber_align.control.health import StatusWrapper
from fiber_align.nodes.ros.diagnostics import ERROR, Health, OK, WARN


class FakeNode:
    """The calls Health makes on a node; the graph queries are counted."""

    def __init__(self, topics, graph, publishers):
        self.subscriptions = [SimpleNamespace(topic_name=t, msg_type=m) for t, m in topics]
        self.graph, self.publishers = graph, publishers
        self.lookups = []
        self.published = []

    def get_topic_names_and_types(self):
        self.lookups.append('*')
        return self.graph

    def get_publishers_info_by_topic(self, topic):
        self.lookups.append(topic)
        return [SimpleNamespace(node_namespace='/', node_name=n, topic_type=t)
                for n, t in self.publishers.get(topic, ())]

    def create_publisher(self, *args):
        return SimpleNamespace(publish=self.published.append)

    def create_timer(self, *args, **kwargs):
        return None

    def set_parameters_atomically(self, parameter_list):
        raise AssertionError('no parameter is set here')

    set_parameters = set_parameters_atomically

    def get_fully_qualified_name(self):
        return '/compensator'

    def get_clock(self):
        return SimpleNamespace(now=lambda: SimpleNamespace(to_msg=lambda: _stamp()))

    def get_logger(self):
        return SimpleNamespace(info=lambda m: None, warning=lambda m: None)


def _stamp():
    from builtin_interfaces.msg import Time
    return Time()


FLOAT, STR = 'std_msgs/msg/Float64', 'std_msgs/msg/String'


def _node(n_topics=12, clash='/t3'):
    topics = [('/t%d' % i, Float64) for i in range(n_topics)]
    graph = [('/t%d' % i, [FLOAT] + ([STR] if '/t%d' % i == clash else []))
             for i in range(n_topics)]
    pubs = {'/t%d' % i: [('ok_%d' % i, FLOAT)] for i in range(n_topics)}
    pubs[clash] = pubs[clash] + [('outsider', STR)]
    return FakeNode(topics, graph, pubs)


def _running_slack():
    slack = Slack(idle_s=60.0)
    slack.after_cycle()             # a cycle just ran: jobs wait for the next ones
    return slack


def test_the_check_is_one_graph_query_per_cycle_and_names_the_foreign_publisher():
    node = _node()
    slack = _running_slack()
    health = Health(node, slack=slack)
    health._report()                # the first report checks the endpoints
    assert node.lookups == [] and len(slack.jobs) == 2
    per_cycle = []
    for _ in range(6):
        before = len(node.lookups)
        slack.after_cycle()
        per_cycle.append(len(node.lookups) - before)
    assert max(per_cycle) <= 1
    # the graph's listing, then only the topic that carries another type
    assert node.lookups == ['*', '/t3']
    health.publish()
    status = node.published[-1].status[0]
    assert status.level == bytes([WARN])
    assert '/t3: /outsider publishes std_msgs/msg/String' in status.message


def test_the_warn_clears_when_the_outsider_is_gone():
    node = _node()
    slack = _running_slack()
    health = Health(node, slack=slack)
    assert health.check_endpoints()             # at once: found
    node.graph = [(t, [FLOAT]) for t, _ in node.graph]
    for _ in range(Health.ENDPOINT_EVERY):
        health._report()
    for _ in range(4):
        slack.after_cycle()
    health.publish()
    assert 'wrong type' not in node.published[-1].status[0].message


def test_without_a_running_cycle_the_check_runs_at_once():
    node = _node(clash='/t7')
    health = Health(node, slack=Slack())        # no cycle yet: jobs run when submitted
    health._report()
    assert node.lookups == ['*', '/t7']
    assert '/outsider' in node.published[-1].status[0].message


class FakeSender:
    """A running sender: the process's graph listing, made on its own thread."""

    running = True

    def __init__(self, graph):
        self.graph, self.watched = graph, []

    def writer(self, pub, volatile):
        return pub

    def watch_graph(self, node, period_s):
        self.watched.append(period_s)

    def graph_topics(self):
        return self.graph

    def stats(self):
        return {}


def test_with_a_sender_the_listing_is_the_processs_not_a_query_on_the_control_thread():
    node = _node()
    sender = FakeSender(node.graph)
    slack = _running_slack()
    health = Health(node, period_s=0.5, slack=slack, sender=sender)
    assert sender.watched == [0.5 * Health.ENDPOINT_EVERY]
    health._report()
    for _ in range(6):
        slack.after_cycle()
    assert node.lookups == ['/t3']          # no listing of its own: the sender's
    health.publish()
    assert '/t3: /outsider publishes std_msgs/msg/String' in \
        node.published[-1].status[0].message


def test_a_task_fills_a_status_of_its_own_named_as_the_updater_names_it():
    node = FakeNode([], [], {})
    health = Health(node)
    health.summary(OK, 'running')

    def temperature(stat):
        stat.summary(WARN, 'warm')
        stat.add('temperature_k', 330.0)
    health.add('temperature', temperature)
    health.force_update()
    own, task = node.published[-1].status
    assert own.name == '/compensator' and own.message == 'running'
    assert own.level == bytes([OK])
    assert task.name == '/compensator: temperature' and task.message == 'warm'
    assert task.level == bytes([WARN])
    assert [(v.key, v.value) for v in task.values] == [('temperature_k', '330.0')]


def test_a_task_object_and_a_failing_task():
    node = FakeNode([], [], {})
    health = Health(node)

    class Task:
        name = 'broken'

        def run(self, stat):
            raise RuntimeError('no sensor')
    health.add(Task())
    health.force_update()
    task = node.published[-1].status[1]
    assert task.name == '/compensator: broken' and task.level == bytes([ERROR])
    assert 'RuntimeError: no sensor' in task.message


def test_status_is_the_old_name_of_summary():
    node = FakeNode([], [], {})
    health = Health(node)
    health.summary(WARN, 'limits off')
    health.publish()
    st = node.published[-1].status
    assert len(st) == 1 and st[0].level == bytes([WARN]) and st[0].message == 'limits off'


def test_merge_summary_keeps_the_worse_and_joins_equals():
    stat = StatusWrapper('x')
    stat.merge_summary(WARN, 'a')
    stat.merge_summary(OK, 'fine')
    stat.merge_summary(WARN, 'b')
    assert (stat.level, stat.message) == (WARN, 'a; b')
    stat.merge_summary(ERROR, 'c')
    assert (stat.level, stat.message) == (ERROR, 'c')
