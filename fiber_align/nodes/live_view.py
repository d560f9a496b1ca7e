# SPDX-License-Identifier: Apache-2.0
"""
``live_view``: the graph's topics served to Foxglove over its WebSocket protocol.

A process of its own (never inside ``control_graph``): the Foxglove SDK's server fed from
raw subscriptions that no executor spins, so a message goes from DDS to the client as the
CDR bytes it was published as; per-sample topics decimated to ``ui_rate_hz``, the state
topics message by message, the optical power in dBm, the alignment state and (the rig)
the power map of the search as JSON channels. Channels, costs, parameters
(``config/live_view.yaml``) and failures: docs/live_view.md.
"""

import functools
import os
import sys
import time

from rclpy.node import Node

from fiber_align.analysis import liveview as lv
from fiber_align.analysis import powermap
from fiber_align.config import ConfigError, load_params
from fiber_align.graph.ranges import LIVE_VIEW_MAP, LIVE_VIEW_RANGES
from fiber_align.graph.registry import NODES
from fiber_align.nodes._msgtypes import message_class
from fiber_align.nodes.ros.params import declare, node_defaults
from fiber_align.nodes.ros.qos import profile
from fiber_align.nodes.ros.runtime import run_node

#: the registry's entry of this node: its name and params files
SPEC = NODES['live_view']
#: The map's range: the 2-D sequencer's reachable square (its params file and node).
RANGE_FILE, RANGE_NODE = 'sequencer2d.yaml', 'alignment_sequencer_2d'
RANGE_KEYS = ('range_x_min_m', 'range_x_max_m', 'range_y_min_m', 'range_y_max_m')
#: The rig's topics the map is made of (relative names).
MAP_TOPICS = ('x/displacement', 'y/displacement', 'optical_power')

#: name: (description, low, high), read-only (the graph checks the same table)
PARAMS = LIVE_VIEW_RANGES


class LiveViewNode(Node):
    """Serve the graph's topics, the power map and the alignment state to Foxglove."""

    def __init__(self, **kwargs):
        """Declare the parameters, start the server (or refuse: one line), start looking."""
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        rng = load_params(RANGE_FILE, RANGE_NODE)
        d.update({k: float(rng[k]) for k in RANGE_KEYS if k not in d})
        p = {name: declare(self, d, name, text, lo, hi, True)
             for name, (text, lo, hi) in PARAMS.items()}
        for k in RANGE_KEYS:
            p[k] = declare(self, d, k, *LIVE_VIEW_MAP, True)
        self.p = p
        if p['niceness']:
            os.nice(int(p['niceness']))
        import foxglove
        self.fg = foxglove
        self.listener = lv.Listener()
        try:
            self.server = foxglove.start_server(
                name='fiber_align %s' % self.get_fully_qualified_name(), host=p['host'],
                port=int(p['port']), message_backlog_size=int(p['message_backlog']),
                server_listener=self.listener)
        except RuntimeError as exc:
            raise ConfigError('cannot serve ws://%s:%d: %s (another live view or program '
                              'on that port? choose live_port / port)'
                              % (p['host'], p['port'], str(exc).replace(
                                  'FoxgloveError: ', ''))) from None
        self.url = 'ws://%s:%d' % (p['host'], self.server.port)
        # the taps live on a node no executor spins: DDS keeps the newest messages and
        # the timer below takes them, ui_rate_hz times a second
        self.taps_node = Node(SPEC.node + '_taps', namespace=self.get_namespace(),
                              context=self.context, start_parameter_services=False,
                              use_global_arguments=False, enable_rosout=False)
        names = list(p['topics']) + [t for t in p['extra_topics'] if t not in p['topics']]
        self.wanted = list(dict.fromkeys(self.resolve_topic_name(t) for t in names))
        self.state_topics = {self.resolve_topic_name(t) for t in p['state_topics']}
        self.map_topics = {self.resolve_topic_name(t): k for t, k in zip(
            MAP_TOPICS, ('x', 'y', 'p'))} if p['power_map'] else {}
        self.align_topic = self.resolve_topic_name('alignment_state')
        self.power_topic = self.resolve_topic_name('optical_power')
        self.taps = {}
        self.skipped = set()
        self.schema = functools.lru_cache(None)(lambda t: lv.ros2msg_schema(t, lv.read_msg))
        own = self.get_fully_qualified_name()
        self.ch_align = self._json_channel(own + '/alignment', lv.ALIGNMENT_SCHEMA, 'every '
                                           'alignment_state message, as structured data')
        self.ch_dbm = self._json_channel(own + '/optical_power_dbm', lv.POWER_DBM_SCHEMA,
                                         lv.Decimator(p['ui_rate_hz']).describe())
        self.last_align = None
        self.map = self.ch_map = None
        if p['power_map']:
            self.map = powermap.SearchMap(*(p[k] for k in RANGE_KEYS), p['power_map_cell_m'],
                                          p['power_map_period_s'])
            self.ch_map = self._json_channel(
                own + '/power_map', powermap.GRID_SCHEMA, 'every %g s: the brightest reading per '
                '%g m cell since the search began' % (p['power_map_period_s'],
                                                      p['power_map_cell_m']))
        self.sent = {}
        self.timer = self.create_timer(1.0 / p['ui_rate_hz'], self.poll)
        self.create_timer(p['discovery_period_s'], self.discover)
        self.discover()
        self.get_logger().info('serving %s (Foxglove: Open connection, %s); topics: %s'
                               % (self.url, self.url, ', '.join(self.wanted)))

    def _json_channel(self, topic, schema, decimation):
        return self.fg.Channel(topic, schema=schema, message_encoding='json',
                               metadata={'decimation': decimation})

    # -- discovery ------------------------------------------------------------------
    def discover(self):
        """Advertise every wanted topic whose type a publisher now shows."""
        types = dict(self.get_topic_names_and_types())
        for topic in self.wanted + sorted(set(self.map_topics) - set(self.wanted)):
            if topic in self.taps or topic in self.skipped or topic not in types:
                continue
            if not self.get_publishers_info_by_topic(topic):
                continue
            msgtype = types[topic][0]
            try:
                self._tap(topic, msgtype)
            except Exception as exc:  # noqa: BLE001 - one topic we cannot serve: say so
                self.skipped.add(topic)
                self.get_logger().warning('cannot serve %s (%s): %s' % (topic, msgtype, exc))

    def _tap(self, topic, msgtype):
        p = self.p
        state = topic in self.state_topics
        dec = None if state else lv.Decimator(p['ui_rate_hz'])
        map_key = self.map_topics.get(topic)
        depth = 10 if state else (int(p['power_map_queue_depth']) if map_key else 1)
        channel = None
        if topic in self.wanted:
            channel = self.fg.Channel(
                topic, message_encoding='cdr',
                schema=self.fg.Schema(name=msgtype, encoding='ros2msg',
                                      data=self.schema(msgtype).encode('utf-8')),
                metadata={'ros_type': msgtype, 'decimation': 'every message' if state
                          else dec.describe()})
        tap = self.taps[topic] = lv.Tap(topic, msgtype, None, channel, state, dec, map_key)
        if not tap.lazy:
            self._subscribe(tap, depth)
        self.sent[topic] = 0
        self.get_logger().info('serving %s (%s)' % (topic, msgtype))

    def _subscribe(self, tap, depth=1):
        tap.sub = self.taps_node.create_subscription(message_class(tap.msgtype), tap.topic,
                                                     lambda msg: None, profile(
                                                         depth, tap.state, tap.state), raw=True)

    def _watched(self, tap):
        """Subscribe a lazy tap while a client watches it (or its dBm view); else drop it."""
        want = tap.channel.has_sinks() or tap.topic == self.power_topic and self.ch_dbm.has_sinks()
        if want and tap.sub is None:
            self._subscribe(tap)
        elif not want and tap.sub is not None:
            self.taps_node.destroy_subscription(tap.sub)
            tap.sub = tap.last = None
        return want

    # -- the UI tick ----------------------------------------------------------------
    @staticmethod
    def _take_all(sub, limit):
        out = []
        with sub.handle:
            for _ in range(limit):
                got = sub.handle.take_message(sub.msg_type, True)
                if got is None:
                    break
                out.append(got)
        return out

    def poll(self):
        """Take what arrived on every tap; send the UI frames that are due."""
        now = time.monotonic()
        now_ns = time.time_ns()
        resend = self.listener.take()
        map_events = []
        for tap in tuple(self.taps.values()):
            if tap.lazy and not self._watched(tap):
                continue
            got = self._take_all(tap.sub, tap.sub.qos_profile.depth)
            if tap.map_key and got:
                map_events += [(info.get('source_timestamp', 0), tap.map_key, data)
                               for data, info in got]
            ch = tap.channel
            out = tap.frames(got, ch is not None and ch.id() in resend, now)
            for data in out if ch is not None else ():
                ch.log(data, log_time=now_ns)
                self.sent[tap.topic] += 1
            for data, _ in got if tap.topic == self.align_topic else ():
                self._on_alignment(data, now_ns)
            if out and tap.topic == self.power_topic:
                self.ch_dbm.log(lv.json_bytes(lv.power_dbm_view(lv.float64_value(out[-1]))),
                                log_time=now_ns)
        if self.ch_align.id() in resend and self.last_align is not None:
            self.ch_align.log(self.last_align, log_time=now_ns)
        if self.map is not None:
            self.map.feed(map_events)
            grid = self.map.due(now, now_ns, self.ch_map.id() in resend)
            if grid is not None:
                self.ch_map.log(lv.json_bytes(grid), log_time=now_ns)

    def _on_alignment(self, data, now_ns):
        try:
            view = lv.alignment_view(lv.string_value(data))
        except ValueError as exc:
            self.get_logger().warning('alignment_state not shown: %s' % exc)
            return
        if self.map is not None:
            self.map.on_state(view.get('state'))
        self.last_align = lv.json_bytes(view)
        self.ch_align.log(self.last_align, log_time=now_ns)

    def destroy_node(self):
        """Stop the server and destroy the taps (the UI frames sent go to the log)."""
        # not an exit report of ``sent`` counts: the view publishes nothing on ROS
        self.get_logger().info('UI frames sent: %s' % ', '.join(
            '%s %d' % kv for kv in sorted(self.sent.items())))
        try:
            self.server.stop()
        finally:
            self.taps_node.destroy_node()
        return super().destroy_node()


def main(args=None):
    """Run the view (a port in use, a bad host, bad parameters: one line, exit 2)."""
    return run_node(LiveViewNode, SPEC.node, args, realtime=lambda node: False)


if __name__ == '__main__':
    sys.exit(main())
