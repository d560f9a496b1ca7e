# SPDX-License-Identifier: Apache-2.0
"""
``bringup``: start the fiber_align graph, run a scenario, record, stop, summarise.

Each node runs as its own process (``python -m fiber_align.nodes.<name> --ros-args
--params-file ...``) from one composed params file: the per-area files (plant, optics,
controller, compensator, driver, sequencer, recorder) overlaid by ``config/fiber_align.yaml``,
any ``--params-file`` given here and the command-line overrides, written to one temporary
file with ROS-compatible types. ``--composed`` runs every node in this process on one
executor instead (the recorder stays a process of its own).

Sequence: start the recorder (``--record DIR``) and the nodes; wait until every node is
on the graph; configure and activate ``actuator_driver`` through
``lifecycle_msgs/srv/ChangeState``; wait until every control topic has its publishers
and subscribers (the recorder's included); start the plant (``simulated_actuator/run``);
run the scenario; hold the plant; stop every node (SIGINT, SIGKILL at the deadline) and
the recorder last; print the run's metrics.

Scenarios (one setpoint source each, exactly one message per ``displacement`` sample):

- ``step``, ``sine``, ``triangle``, ``staircase``: this process publishes ``setpoint``
  (m) = reference(t_k) of :mod:`fiber_align.simulation.scenarios`, clamped to what the
  plant can reach, as the offline simulation does.
- ``hysteresis-experiment``: open loop, the 0-72 V, 0.1 Hz triangle (one cycle is 10 s
  of sample time). The compensator and the controller are not started; this process
  publishes ``feedforward_voltage`` = drive(t_k) (V) and ``feedback_voltage`` = 0 V for
  every sample, and the driver sums, clamps and slew-limits them as in closed loop. The
  bag is what ``fiber-align identify BAG`` reads.
- ``align``: ``alignment_sequencer`` is the only setpoint publisher. After 20 ms at rest
  its ``align`` service is called, then bringup waits for ``alignment_state`` TRACKING
  (or FAULT: exit 1), holds 20 ms and runs ``--cycles`` switch cycles (``switch``
  false for 30 ms, true for 60 ms; sample time).
- ``none``: the graph runs until SIGINT; publish ``setpoint`` (m) yourself.

SIGINT or SIGTERM to bringup at any point runs the same clean stop within
``stop_timeout_s`` (5 s). Exit code 0 on a clean run, 1 on a failure (a node died, a
timeout, a stalled graph, another graph on the ROS domain, an alignment FAULT), 2 on a
configuration error (e.g. an unreadable ``--model``), 130 when interrupted.
"""

import argparse
import json
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import yaml

from fiber_align.analysis.report import default_params, hysteresis_metrics
from fiber_align.config import config_path, ConfigError, read_yaml
from fiber_align.control.factory import CONTROLLERS
from fiber_align.jsonout import json_default
from fiber_align.nodes._common import CONTROL_QOS, normalize
from fiber_align.plant.actuator import PARAM_KEYS, SimulatedActuator
from fiber_align.plant.optics import OpticalLink
from fiber_align.simulation import scenarios
from fiber_align.simulation.alignment_scenarios import rise_time
from fiber_align.simulation.metrics import loop_metrics, run_scores, STEP_KEYS
from fiber_align.simulation.simulate import check_model_file, tracking_skip_s

NODES = ('simulated_actuator', 'hysteresis_compensator', 'fuzzy_pid_controller',
         'actuator_driver')
CLASSES = {'simulated_actuator': 'SimulatedActuatorNode',
           'hysteresis_compensator': 'HysteresisCompensatorNode',
           'fuzzy_pid_controller': 'FuzzyPidControllerNode',
           'actuator_driver': 'ActuatorDriverNode',
           'alignment_sequencer': 'AlignmentSequencerNode'}
AREA_FILES = ('plant.yaml', 'optics.yaml', 'controller.yaml', 'compensator.yaml',
              'models/compensator_model.yaml', 'driver.yaml', 'sequencer.yaml',
              'recorder.yaml')
GRAPH_FILE = 'fiber_align.yaml'
SCENARIOS = ('none', 'step', 'sine', 'triangle', 'staircase', 'hysteresis-experiment',
             'align')
TRACKING_SCENARIOS = ('step', 'sine', 'triangle', 'staircase')
SENT_PREFIX = 'FIBER_ALIGN_SENT '
EXIT_OK, EXIT_FAIL, EXIT_INTERRUPTED = 0, 1, 130
#: align scenario timing (s of sample time): rest before ``align``, loss window after
#: TRACKING, switch off and on times, level window at the end of each on time
ALIGN_IDLE_S = 0.02
ALIGN_MAX_S = 1.0
LOSS_WINDOW_S = 0.02
SWITCH_OFF_S = 0.03
SWITCH_ON_S = 0.06
LEVEL_S = 0.01


class BringupError(RuntimeError):
    """The graph could not be brought up or failed while running."""


class StartStall(BringupError):
    """A lockstep graph did not answer its first sample (a message lost at start-up)."""


def _merge(a, b):
    out = dict(a)
    for k, v in b.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _nest(name, value):
    """Return ``{'a': {'b': value}}`` for the ROS dotted name ``a.b``."""
    parts = name.split('.')
    out = value
    for p in reversed(parts):
        out = {p: out}
    return out


def compose_params(extra_files=(), overrides=None):
    """
    Return the merged params mapping ``{node: {ros__parameters: ...}}`` of the graph.

    :param extra_files: user params files applied after the per-area files and
        ``fiber_align.yaml``.
    :param overrides: ``{node or '/**': {name: value}}`` applied last; dotted names
        (``optics.slot_position_m``) are nested.
    """
    data = {}
    for f in list(AREA_FILES) + [GRAPH_FILE] + list(extra_files):
        try:
            p = config_path(f)
        except Exception:  # noqa: BLE001 - an optional area file may be missing
            if f in AREA_FILES:
                continue
            raise
        data = _merge(data, read_yaml(p))
    for node, params in (overrides or {}).items():
        for name, value in params.items():
            data = _merge(data, {node: {'ros__parameters': _nest(name, value)}})
    return normalize(data)


def node_params(data, node):
    """Return the effective parameters of ``node`` in a composed mapping (``/**`` first)."""
    out = dict(data.get('/**', {}).get('ros__parameters', {}))
    out.update(data.get(node, {}).get('ros__parameters', {}))
    return out


def namespaced(data, namespace):
    """Return the params mapping with node sections keyed ``/<namespace>/<node>``."""
    ns = namespace.strip('/')
    if not ns:
        return data
    return {(k if k.startswith('/') else '/%s/%s' % (ns, k)): v for k, v in data.items()}


def graph_nodes(scenario):
    """Return the node names (processes) the scenario runs, recorder excluded."""
    if scenario == 'hysteresis-experiment':
        return ('simulated_actuator', 'actuator_driver')
    if scenario == 'align':
        return NODES + ('alignment_sequencer',)
    return NODES


def expected_endpoints(scenario, lockstep, record):
    """
    Return ``{topic: (publishers, subscribers)}`` the running graph must have.

    :param scenario: a name in :data:`SCENARIOS`.
    :param lockstep: the plant publishes ``/clock``.
    :param record: a recorder subscribes to every topic too.
    """
    rec = 1 if record else 0
    if scenario == 'hysteresis-experiment':
        out = {'displacement': (1, 1), 'feedforward_voltage': (1, 1),
               'feedback_voltage': (1, 1), 'drive_voltage': (1, 2), 'optical_power': (1, 0)}
    else:
        out = {'displacement': (1, 2), 'setpoint': (0 if scenario == 'none' else 1, 2),
               'feedforward_voltage': (1, 1), 'feedback_voltage': (1, 1),
               'controller_state': (1, 0), 'drive_voltage': (1, 2), 'optical_power': (1, 0)}
    if scenario == 'align':
        out.update({'displacement': (1, 3), 'setpoint': (1, 3), 'optical_power': (1, 2),
                    'alignment_state': (1, 1)})
    if lockstep:
        out['/clock'] = (1, 0)
    return {k: (p, s + (rec if p else 0)) for k, (p, s) in out.items()}


class Reference:
    """Setpoint source of a scenario: ``value(t)`` (m) for a sample time ``t`` (s)."""

    def __init__(self, name, reach_m):
        """Use the scenario generator of the control core; clamp to [0, reach_m] (m)."""
        self.scenario = scenarios.make(name)
        self.reach = float(reach_m)

    def value(self, t):
        """Return the clamped reference (m) at ``t`` (s)."""
        r = self.scenario.reference(t)
        return min(max(r, 0.0), self.reach)


class OpenLoopDrive:
    """Open-loop drive of ``hysteresis-experiment``: ``value(t)`` (V) at sample time t (s)."""

    def __init__(self):
        """Use the scenario generator of the control core (0-72 V triangle, 0.1 Hz)."""
        self.scenario = scenarios.make('hysteresis-experiment')

    def value(self, t):
        """Return the drive (V) at ``t`` (s)."""
        return self.scenario.drive(t)


class Runner:
    """
    The bringup's own ROS nodes: scenario source, trace recorder, service clients.

    ``mode`` is ``reference`` (publish one ``setpoint`` per displacement sample),
    ``open-loop`` (publish one ``feedforward_voltage`` and one 0 V ``feedback_voltage``
    per sample) or ``observe`` (publish nothing; record the setpoints, optical power and
    ``alignment_state`` of the graph). The topic node is spun by an executor thread; the
    service clients live on a second node that only the calling thread spins, so a call
    never waits on the executor thread.
    """

    def __init__(self, namespace, mode, source, lockstep, rate_hz):
        """Create the nodes, their clients and the scenario transport."""
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
        self.mode = mode
        self.source = source
        self.lockstep = lockstep
        self.period = 1.0 / rate_hz
        self.Float64 = Float64
        self.pub_sp = self.pub_ff = self.pub_fb = None
        if mode == 'reference':
            self.pub_sp = self.node.create_publisher(Float64, 'setpoint', CONTROL_QOS)
        elif mode == 'open-loop':
            self.pub_ff = self.node.create_publisher(Float64, 'feedforward_voltage',
                                                     CONTROL_QOS)
            self.pub_fb = self.node.create_publisher(Float64, 'feedback_voltage', CONTROL_QOS)
        self.node.create_subscription(JointState, 'displacement', self._on_disp, CONTROL_QOS)
        self.node.create_subscription(Float64, 'drive_voltage', self._on_drive, CONTROL_QOS)
        if mode == 'observe':
            state_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                   reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.node.create_subscription(Float64, 'setpoint', self._on_setpoint,
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
        self.active = False          # record samples (and publish, in the source modes)
        self.t0 = None
        self.duration = math.inf
        self.done = threading.Event()
        self.t, self.r, self.y, self.v, self.p = [], [], [], [], []
        self.states = []             # (sample index, status dict) of alignment_state
        self.n_sent = {}
        self.progress = time.monotonic()   # wall time of the latest recorded sample
        self.last = None                   # (t, y) of the last sample, answered by finish()
        self.hold = None                   # future of the plant's hold before it
        self.stall_s = 10.0
        self.start_stall_s = 3.0
        self.started = time.monotonic()
        self.lock = threading.Lock()

    @property
    def samples(self):
        """Return the number of displacement samples recorded so far."""
        return len(self.y)

    def _count(self, topic):
        self.n_sent[topic] = self.n_sent.get(topic, 0) + 1

    def _on_disp(self, msg):
        if not self.active:
            return
        ts = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        if self.t0 is None:
            self.t0 = ts
        t = round((ts - self.t0) / self.period) * self.period if self.lockstep else ts - self.t0
        if t >= self.duration - 0.5 * self.period:
            self.active = False
            self.done.set()
            return
        y = msg.position[0] if len(msg.position) else math.nan
        if self.mode != 'observe' and t + self.period >= self.duration - 0.5 * self.period:
            # The last sample: hold the plant first, answer once the hold is confirmed
            # (finish()), so no sample follows and the bag ends with a command for every
            # displacement sample.
            from std_srvs.srv import SetBool
            self.active = False
            self.last = (t, y)
            self.hold = self.run_cli.call_async(SetBool.Request(data=False))
            return
        self._emit(t, y)

    def finish(self):
        """Answer the last sample once the plant's hold is confirmed; return True when done."""
        if self.done.is_set():
            return True
        if self.hold is None or not self.hold.done():
            return False
        self._emit(*self.last)
        self.done.set()
        return True

    def _emit(self, t, y):
        """Publish the source's message(s) for sample time ``t`` (s); record the sample."""
        r = math.nan
        if self.mode == 'reference':
            r = self.source.value(t)
            self.pub_sp.publish(self.Float64(data=r))
            self._count('setpoint')
        elif self.mode == 'open-loop':
            u = self.source.value(t)
            self.pub_ff.publish(self.Float64(data=u))
            self._count('feedforward_voltage')
            self.pub_fb.publish(self.Float64(data=0.0))
            self._count('feedback_voltage')
        self.progress = time.monotonic()
        with self.lock:
            self.t.append(t)
            self.y.append(y)
            if self.mode != 'observe':
                self.r.append(r)

    def _on_drive(self, msg):
        if self.active or self.v:
            with self.lock:
                self.v.append(msg.data)

    def _on_setpoint(self, msg):
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
            self.states.append((len(self.y), st))

    def state(self):
        """Return the latest ``alignment_state`` status dict (``{}`` before the first)."""
        with self.lock:
            return dict(self.states[-1][1]) if self.states else {}

    def call(self, client, request, timeout):
        """Call a service with a bounded wait (s); return the response."""
        if not client.wait_for_service(timeout_sec=timeout):
            raise BringupError('service %s not available within %g s'
                               % (client.srv_name, timeout))
        fut = client.call_async(request)
        self.cexec.spin_until_future_complete(fut, timeout_sec=timeout)
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

    def activate_driver(self, timeout):
        """Configure and activate the driver through lifecycle_msgs/srv/ChangeState."""
        from lifecycle_msgs.msg import State, Transition
        from lifecycle_msgs.srv import ChangeState, GetState
        for tid, label in ((Transition.TRANSITION_CONFIGURE, 'configure'),
                           (Transition.TRANSITION_ACTIVATE, 'activate')):
            req = ChangeState.Request()
            req.transition.id = tid
            if not self.call(self.change, req, timeout).success:
                raise BringupError('actuator_driver refused to %s' % label)
        st = self.call(self.get_state, GetState.Request(), timeout)
        if st.current_state.id != State.PRIMARY_STATE_ACTIVE:
            raise BringupError('actuator_driver is %s, not active' % st.current_state.label)

    def wait_matched(self, topics, timeout, alive=lambda: None):
        """Wait until each topic has at least ``(publishers, subscribers)`` (bounded, s)."""
        end = time.monotonic() + timeout
        while True:
            alive()
            short = []
            for topic, (np_, ns_) in topics.items():
                name = self.node.resolve_topic_name(topic)
                have = (self.node.count_publishers(name), self.node.count_subscribers(name))
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
            n = self.node.count_publishers(self.node.resolve_topic_name(topic))
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
        if self.lockstep and self.samples < 2 and self.last is None and \
                now - self.started > self.start_stall_s:
            raise StartStall('the first sample was not answered within %g s'
                             % self.start_stall_s)
        quiet = now - self.progress
        if quiet > self.stall_s:
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


class Child:
    """One node process; relays its output and collects its sent-count report."""

    def __init__(self, name, cmd, env, quiet):
        """Start the process in its own session (a terminal Ctrl-C reaches bringup only)."""
        self.name = name
        self.sent = None
        self.quiet = quiet
        self.proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, bufsize=1,
                                     start_new_session=True)
        self.thread = threading.Thread(target=self._relay, daemon=True)
        self.thread.start()

    def _relay(self):
        for line in self.proc.stdout:
            if line.startswith(SENT_PREFIX):
                try:
                    self.sent = json.loads(line[len(SENT_PREFIX):])['sent']
                except (ValueError, KeyError):
                    pass
                continue
            if not self.quiet:
                sys.stdout.write('[%s] %s' % (self.name, line))
                sys.stdout.flush()

    def alive(self):
        """Return True while the process runs."""
        return self.proc.poll() is None

    def interrupt(self):
        """Send SIGINT (the nodes' clean shutdown)."""
        if self.alive():
            self.proc.send_signal(signal.SIGINT)

    def wait(self, timeout):
        """Wait for exit; SIGKILL after ``timeout`` s. Return the exit code."""
        try:
            self.proc.wait(timeout=max(0.0, timeout))
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=5)
        self.thread.join(timeout=1.0)
        return self.proc.returncode


def parse_args(argv):
    """Parse the command line (ROS arguments after ``--ros-args`` are ignored)."""
    if argv is None:
        argv = sys.argv[1:]
    if '--ros-args' in argv:
        argv = argv[:argv.index('--ros-args')]
    ap = argparse.ArgumentParser(prog='bringup', description=__doc__.strip().split('\n')[0])
    ap.add_argument('--scenario', choices=SCENARIOS, default=None,
                    help='scenario to run (default: bringup.scenario of fiber_align.yaml)')
    ap.add_argument('--duration', type=float, default=None,
                    help="scenario length (s of sample time; default: the scenario's)")
    ap.add_argument('--sync', choices=('realtime', 'lockstep'), default=None,
                    help='sample clock (default: sync_mode of fiber_align.yaml)')
    ap.add_argument('--controller', choices=CONTROLLERS, default='composite')
    ap.add_argument('--model', metavar='FILE', default=None,
                    help='PI model params file for the compensator (e.g. from fiber-align '
                         'identify, or config/hysteresis_paper.yaml)')
    ap.add_argument('--rate', type=float, default=None, help='control rate (Hz)')
    ap.add_argument('--seed', type=int, default=None, help='plant sensor-noise seed')
    ap.add_argument('--no-noise', action='store_true', help='sensor noise off')
    ap.add_argument('--cycles', type=int, default=None,
                    help='align: switch off/on cycles after TRACKING (default 5)')
    ap.add_argument('--record', metavar='DIR', default=None, help='record a bag into DIR')
    ap.add_argument('--storage', choices=('mcap', 'sqlite3'), default=None)
    ap.add_argument('--composed', action='store_true',
                    help='all nodes in this process on one executor')
    ap.add_argument('--namespace', default='', help='namespace of the whole graph')
    ap.add_argument('--params-file', action='append', default=[],
                    help='extra params file (applied after config/fiber_align.yaml)')
    ap.add_argument('-p', '--param', action='append', default=[], metavar='NODE:NAME:=VALUE',
                    help='override one parameter (NODE may be **)')
    ap.add_argument('--trace', metavar='CSV', help='write t_s,r_m,y_m of every sample')
    ap.add_argument('--summary', metavar='JSON', help='write the summary as JSON')
    ap.add_argument('--quiet', action='store_true', help="do not relay the nodes' output")
    return ap.parse_args(argv)


def _param_overrides(args, graph):
    ov = {'/**': {}, 'simulated_actuator': {'autostart': False}}
    sync = args.sync or graph.get('sync_mode', 'realtime')
    ov['/**']['sync_mode'] = sync
    ov['/**']['controller'] = args.controller
    if args.seed is not None:
        ov['simulated_actuator']['seed'] = int(args.seed)
    if args.no_noise:
        ov['simulated_actuator']['noise_rms_m'] = 0.0
    if args.model:
        path = os.path.abspath(args.model)
        check_model_file(path)
        ov['hysteresis_compensator'] = {'model_file': path}
    for item in args.param:
        node, _, rest = item.partition(':')
        name, _, value = rest.partition(':=')
        if not name or not _:
            raise SystemExit('bringup: -p wants NODE:NAME:=VALUE, got %r' % item)
        ov.setdefault('/**' if node in ('**', '/**') else node, {})[name] = \
            yaml.safe_load(value)
    return ov, sync


def main(args=None):
    """Bring the graph up, run, stop, summarise; return (and exit with) the exit code."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    a = parse_args(args)
    try:
        b = Bringup(a)
    except (ConfigError, ValueError) as exc:
        print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
        code = 2
    else:
        code = b.run()
    if args is None:
        sys.exit(code)
    return code


class Bringup:
    """One bring-up: processes (or composed nodes), orchestration, stop and summary."""

    def __init__(self, args):
        """Compose the parameters and decide what runs."""
        self.args = args
        if args.record and os.path.exists(args.record):
            raise ValueError('--record %s exists already; choose a new bag directory'
                             % args.record)
        graph0 = compose_params(args.params_file)
        gp = node_params(graph0, 'bringup')
        self.scenario = args.scenario or gp.get('scenario', 'none')
        ov, self.sync = _param_overrides(args, node_params(graph0, 'simulated_actuator'))
        rate = args.rate or float(node_params(graph0, 'simulated_actuator')['rate_hz'])
        ov['/**']['rate_hz'] = float(rate)
        self.rate = float(rate)
        self.params = compose_params(args.params_file, ov)
        self.gp = node_params(self.params, 'bringup')
        dur = args.duration if args.duration is not None else float(gp.get('duration_s', 0))
        self.duration = dur
        self.cycles = args.cycles if args.cycles is not None else int(
            self.gp.get('switch_cycles', 5))
        self.names = graph_nodes(self.scenario)
        self.children = []
        self.nodes = []
        self.runner = None
        self.executor = None
        self.spin_thread = None
        self.tmp = tempfile.TemporaryDirectory(prefix='fiber_align_bringup_')
        self.params_file = str(Path(self.tmp.name) / 'fiber_align_params.yaml')
        with open(self.params_file, 'w', encoding='utf-8') as f:
            yaml.safe_dump(namespaced(self.params, args.namespace), f, sort_keys=False)
        self.stopping = False
        self.interrupted = False
        self.endpoints = {}          # topic -> (publishers, subscribers) once matched
        self._next_check = 0.0
        self.summary = {}

    # -- processes ------------------------------------------------------------------
    def _ros_args(self, name):
        out = ['--ros-args', '--params-file', self.params_file]
        if self.args.namespace.strip('/'):
            out += ['-r', '__ns:=/' + self.args.namespace.strip('/')]
        return out

    def _spawn(self, module, name, extra=()):
        cmd = [sys.executable, '-m', module] + self._ros_args(name) + list(extra)
        ch = Child(name, cmd, dict(os.environ), self.args.quiet)
        self.children.append(ch)
        print('bringup: started %s (pid %d)' % (name, ch.proc.pid), flush=True)

    def _alive(self):
        for ch in self.children:
            if not ch.alive():
                raise BringupError('%s exited with code %s' % (ch.name, ch.proc.returncode))
        now = time.monotonic()
        if self.endpoints and self.runner is not None and now >= self._next_check:
            self._next_check = now + 1.0
            extra = self.runner.foreign_publishers(self.endpoints)
            if extra:
                raise BringupError(
                    'another graph shares ROS_DOMAIN_ID=%s: %s; run on a domain of its own'
                    % (os.environ.get('ROS_DOMAIN_ID', '0'), ', '.join(extra)))

    def _recorder_args(self):
        rec = ['-p', 'output:=%s' % os.path.abspath(self.args.record)]
        if self.args.storage:
            rec += ['-p', 'storage:=%s' % self.args.storage]
        return rec

    def _plant(self):
        p = node_params(self.params, 'simulated_actuator')
        keys = PARAM_KEYS
        return SimulatedActuator.from_params({k: p[k] for k in keys if k in p})

    # -- run ------------------------------------------------------------------------
    def run(self):
        """Run the whole bring-up; return the exit code."""
        import rclpy
        from rclpy.signals import SignalHandlerOptions
        signal.signal(signal.SIGTERM, _raise_interrupt)
        rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
        code = EXIT_OK
        retries = int(self.gp.get('start_retries', 2))
        try:
            for attempt in range(retries + 1):
                try:
                    self._start()
                    self._run_scenario()
                    break
                except StartStall as exc:
                    if attempt == retries:
                        raise
                    print('bringup: %s (a message lost at start-up); restarting the graph'
                          % exc, flush=True)
                    self._stop()
                    lost = {n: c for n, c in self.summary.get('sent', {}).items() if c}
                    print('bringup: the stalled attempt sent %s' % json.dumps(lost), flush=True)
                    self.summary.setdefault('stalled_attempts', []).append(lost)
                    self._reset()
                    self.summary['restarts'] = attempt + 1
        except KeyboardInterrupt:
            print('bringup: interrupted, stopping', flush=True)
            code = EXIT_INTERRUPTED
            self.interrupted = True
            self.summary['interrupted'] = True
        except BringupError as exc:
            print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
            self.summary['error'] = str(exc)
            code = EXIT_FAIL
        finally:
            try:
                self._stop()
            except KeyboardInterrupt:
                self.interrupted = True
                self._stop()
                code = EXIT_INTERRUPTED
            self._report()
            rclpy.try_shutdown()
            self.tmp.cleanup()
        return code

    def _reset(self):
        """Forget a stopped attempt: processes, nodes, runner, its bag and its summary."""
        import shutil
        self.children, self.nodes, self.runner, self.executor = [], [], None, None
        self.endpoints, self._next_check = {}, 0.0
        self.stopping = False
        for k in ('sent', 'recorded', 'children', 'stop_s', 'recorder_catch_up_s',
                  'startup_s', 'run_wall_s'):
            self.summary.pop(k, None)
        if self.args.record and os.path.isdir(self.args.record):
            shutil.rmtree(self.args.record)

    def _start(self):
        from rclpy.executors import SingleThreadedExecutor
        t_start = time.monotonic()
        timeout = float(self.gp.get('startup_timeout_s', 30.0))
        lockstep = self.sync == 'lockstep'
        if self.scenario in TRACKING_SCENARIOS:
            mode, source = 'reference', Reference(self.scenario, self._plant().reachable_m())
        elif self.scenario == 'hysteresis-experiment':
            mode, source = 'open-loop', OpenLoopDrive()
        else:
            mode, source = 'observe', None
        if source is not None and self.duration <= 0:
            self.duration = source.scenario.duration_s
        self.executor = SingleThreadedExecutor()
        self.runner = Runner(self.args.namespace, mode, source, lockstep, self.rate)
        self.runner.stall_s = float(self.gp.get('stall_timeout_s', 10.0))
        self.runner.start_stall_s = float(self.gp.get('start_stall_timeout_s', 3.0))
        self.executor.add_node(self.runner.node)
        if self.args.record:
            self._spawn('fiber_align.nodes.bag_recorder', 'bag_recorder',
                        self._recorder_args())
        if self.args.composed:
            self._compose(self.names)
        else:
            for n in self.names:
                self._spawn('fiber_align.nodes.' + n, n)
        self.spin_thread = threading.Thread(target=self._spin, daemon=True)
        self.spin_thread.start()
        all_names = list(self.names) + (['bag_recorder'] if self.args.record else [])
        self.runner.wait_nodes(all_names, timeout, self._alive)
        self.runner.activate_driver(timeout)
        want = expected_endpoints(self.scenario, lockstep, bool(self.args.record))
        self.runner.wait_matched(want, timeout, self._alive)
        self.endpoints = want
        self._alive()
        # The graph as this process sees it is complete; give every other participant
        # the time to match its writers to the new readers too (a sample published
        # before that is lost for the reader, and lockstep would stall).
        quick = self.args.composed and not self.args.record
        time.sleep(float(self.gp.get('match_settle_s', 0.1 if quick else 0.5)))
        self.summary['startup_s'] = time.monotonic() - t_start
        print('bringup: graph up in %.2f s (%s, %g Hz, %s, %s)'
              % (self.summary['startup_s'], self.sync, self.rate, self.args.controller,
                 'composed' if self.args.composed else 'multi-process'), flush=True)

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - executor shut down at exit
            pass

    def _compose(self, names):
        # One SingleThreadedExecutor (not the EventsExecutor: a service call from another
        # thread while it spins can deadlock in rclpy Jazzy).
        import importlib
        for n in names:
            mod = importlib.import_module('fiber_align.nodes.' + n)
            cls = getattr(mod, CLASSES.get(n, ''), None)
            if cls is None:
                raise BringupError('%s cannot be composed' % n)
            node = cls(cli_args=self._ros_args(n))
            self.nodes.append(node)
            self.executor.add_node(node)

    def _run_scenario(self):
        r = self.runner
        if self.scenario == 'none':
            r.active = True
            r.set_running(True)
            print('bringup: running; publish `setpoint` (m). Ctrl-C stops.', flush=True)
            while True:
                self._alive()
                time.sleep(0.1)
        t0 = time.monotonic()
        if self.scenario == 'align':
            r.start()
            r.set_running(True)
            try:
                self._align()
            finally:
                self.summary['run_wall_s'] = time.monotonic() - t0
            return
        r.duration = self.duration
        r.start()
        r.set_running(True)
        wall_limit = 60.0 + 20.0 * self.duration
        while not r.finish():
            r.cexec.spin_once(timeout_sec=0.02)
            self._alive()
            r.check_stall()
            if time.monotonic() - t0 > wall_limit:
                raise BringupError('scenario did not finish within %g s' % wall_limit)
        self.summary['run_wall_s'] = time.monotonic() - t0

    def _align(self):
        """Align, hold, run the switch cycles (sample-time waits, bounded wall time)."""
        from std_srvs.srv import SetBool, Trigger
        r = self.runner
        k = self._ticks
        wall = 30.0 + 40.0 * (ALIGN_MAX_S + self.cycles * (SWITCH_OFF_S + SWITCH_ON_S))
        r.wait_samples(k(ALIGN_IDLE_S), wall, self._alive)
        events = {}
        res = r.call(r.align_cli, Trigger.Request(), 10.0)
        events['align'] = r.samples
        if not res.success:
            raise BringupError('align refused: %s' % res.message)

        def settled():
            return r.state().get('state') in ('TRACKING', 'FAULT')
        r.wait_samples(events['align'] + k(ALIGN_MAX_S), wall, self._alive, settled)
        st = r.state()
        if st.get('state') != 'TRACKING':
            self.summary['align_events'] = events
            raise BringupError('alignment ended in %s: %s'
                               % (st.get('state'), st.get('fault_reason') or 'timeout'))
        events['tracking'] = self._state_sample('TRACKING', events['align'])
        r.wait_samples(events['tracking'] + k(LOSS_WINDOW_S), wall, self._alive)
        cyc = []
        for _ in range(self.cycles):
            res = r.call(r.switch_cli, SetBool.Request(data=False), 10.0)
            k_off = r.samples
            if not res.success:
                raise BringupError('switch off refused: %s' % res.message)
            r.wait_samples(k_off + k(SWITCH_OFF_S), wall, self._alive)
            res = r.call(r.switch_cli, SetBool.Request(data=True), 10.0)
            k_on = r.samples
            if not res.success:
                raise BringupError('switch on refused: %s' % res.message)
            r.wait_samples(k_on + k(SWITCH_ON_S), wall, self._alive)
            cyc.append((k_off, k_on, r.samples))
            if r.state().get('state') == 'FAULT':
                break
        events['cycles'] = cyc
        self.summary['align_events'] = events
        if r.state().get('state') != 'TRACKING':
            st = r.state()
            raise BringupError('switch cycles ended in %s: %s'
                               % (st.get('state'), st.get('fault_reason')))

    def _ticks(self, seconds):
        return int(round(seconds * self.rate))

    def _state_sample(self, state, after):
        with self.runner.lock:
            for k, st in self.runner.states:
                if st.get('state') == state and k >= after:
                    return k
        return self.runner.samples

    # -- stop -----------------------------------------------------------------------
    def _stop(self):
        """Hold the plant, SIGINT the nodes, then the recorder, all within stop_timeout_s."""
        if self.stopping:
            # a second interrupt: just make sure everything dies
            for ch in self.children:
                ch.wait(0.5)
            return
        self.stopping = True
        t_stop = time.monotonic()
        stop_s = float(self.gp.get('stop_timeout_s', 5.0))
        deadline = t_stop + max(1.0, stop_s - 0.5)
        r = self.runner
        if r is not None:
            r.active = False
            try:
                if r.run_cli.service_is_ready() and not any(
                        not ch.alive() for ch in self.children if ch.name == 'simulated_actuator'):
                    r.set_running(False, timeout=0.5)
            except BringupError:
                pass
            time.sleep(0.1)   # in-flight messages reach their subscribers
        nodes = [ch for ch in self.children if ch.name != 'bag_recorder']
        rec = [ch for ch in self.children if ch.name == 'bag_recorder']
        if rec and rec[0].alive():
            # the graph is held: let the recorder work through its backlog before the
            # publishers go (a writer that exits takes its undelivered samples with it)
            limit = (deadline - 2.5 - time.monotonic()) if self.interrupted else 30.0
            self.summary['recorder_catch_up_s'] = wait_idle(rec[0].proc.pid, max(0.2, limit))
        for ch in nodes:
            ch.interrupt()
        node_deadline = deadline - (1.5 if rec else 0.0)
        for ch in nodes:
            ch.wait(node_deadline - time.monotonic())
        if self.nodes:
            self.summary['sent'] = {n.get_name(): n.sent_counts() for n in self.nodes}
        if self.executor is not None:
            self.executor.shutdown(timeout_sec=0.5)
        for n in self.nodes:
            n.destroy_node()
        for ch in rec:
            ch.interrupt()
            ch.wait(deadline - time.monotonic())
        if r is not None:
            self.summary.setdefault('sent', {})['bringup'] = dict(r.n_sent)
            r.destroy()
        for ch in self.children:
            if ch.sent is not None:
                self.summary.setdefault('sent', {})[ch.name] = ch.sent
        self.summary['children'] = {ch.name: {'pid': ch.proc.pid,
                                              'exit_code': ch.proc.returncode}
                                    for ch in self.children}
        self.summary['stop_s'] = time.monotonic() - t_stop
        if self.args.record:
            counts = Path(self.args.record) / 'recorder_counts.json'
            if counts.is_file():
                self.summary['recorded'] = json.loads(counts.read_text(encoding='utf-8'))

    # -- summary --------------------------------------------------------------------
    def _report(self):
        s = self.summary
        s.update({'scenario': self.scenario, 'sync_mode': self.sync, 'rate_hz': self.rate,
                  'controller': self.args.controller, 'composed': bool(self.args.composed),
                  'namespace': self.args.namespace.strip('/'),
                  'model_file': os.path.abspath(self.args.model) if self.args.model else None,
                  'record': os.path.abspath(self.args.record) if self.args.record else None})
        r = self.runner
        if r is not None:
            t, ref, y = r.trace()
            s['samples'] = int(t.size)
            if t.size > 2 and self.scenario in TRACKING_SCENARIOS:
                s['metrics'] = scenario_metrics(self.scenario, t, ref, y, r.series('v'))
            elif t.size > 2 and self.scenario == 'hysteresis-experiment':
                s['metrics'] = hysteresis_metrics(r.series('v'), y)
            elif t.size > 2 and self.scenario == 'align':
                s['align'] = align_metrics(t, y, r.series('p'), r.states,
                                           s.get('align_events', {}), self.params, self.rate)
            if self.args.trace and t.size:
                np.savetxt(self.args.trace, np.column_stack([t, ref, y]), delimiter=',',
                           header='t_s,r_m,y_m', comments='')
        print(format_summary(s), flush=True)
        if self.args.summary:
            with open(self.args.summary, 'w', encoding='utf-8') as f:
                json.dump(s, f, indent=1, default=json_default)


def cpu_time_s(pid):
    """Return the user + system CPU time (s) of process ``pid``, or NaN if it is gone."""
    try:
        with open('/proc/%d/stat' % pid, encoding='ascii') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return math.nan


def wait_idle(pid, limit_s, window_s=0.1, busy_s=0.011, quiet_windows=2):
    """
    Wait until process ``pid`` is idle; return the wall time waited (s).

    Idle: at most ``busy_s`` CPU seconds in each of ``quiet_windows`` consecutive
    ``window_s`` windows (s); the wait is bounded by ``limit_s`` (s wall).
    """
    t0 = time.monotonic()
    last, quiet = cpu_time_s(pid), 0
    while time.monotonic() - t0 < limit_s:
        time.sleep(window_s)
        now = cpu_time_s(pid)
        if not math.isfinite(now):
            break
        quiet = quiet + 1 if now - last <= busy_s else 0
        last = now
        if quiet >= quiet_windows:
            break
    return time.monotonic() - t0


def scenario_skip_s(name, t_end_s):
    """
    Return the leading time (s) left out of the tracking metrics of a scenario.

    As ``fiber-align simulate`` (:func:`fiber_align.simulation.simulate.tracking_skip_s`):
    step and staircase the first half of the run; sine and triangle one period, or
    nothing when the run (``t_end_s``, s) is not longer than that.
    """
    return tracking_skip_s(scenarios.make(name), np.array([0.0, float(t_end_s)]))


def scenario_metrics(name, t, r, y, v=None):
    """
    Return step and tracking metrics (SI) of a measured trace.

    Computed by :func:`fiber_align.simulation.metrics.loop_metrics`, the function
    ``fiber-align analyze`` and ``fiber-align simulate`` use, with the ``analyze``
    settings of ``config/recorder.yaml``: the worst settling time (2 % band), overshoot
    and rise time over the setpoint steps, and the tracking errors after
    :func:`scenario_skip_s`.
    """
    ap = default_params()
    lm = loop_metrics(t, r, y, v, skip_s=scenario_skip_s(name, float(t[-1] - t[0])),
                      step_min_m=float(ap.get('step_min_m', 1e-6)),
                      band=float(ap.get('settling_band', 0.02)))
    out = run_scores(lm)
    if name not in ('step', 'staircase'):
        out = {k: v for k, v in out.items() if k not in STEP_KEYS}
    out.update(lm.get('tracking', {}))      # with mean_error_m
    return {k: float(v) for k, v in out.items() if isinstance(v, (int, float))}


def align_metrics(t, y, p, states, events, params, rate_hz):
    """
    Return the alignment figures of an ``align`` run (SI; losses in dB).

    Losses are true coupling losses of the measured tip position against the slot of the
    optics model (``optics.*`` of ``simulated_actuator``); the 10 nm sensor noise adds
    under 1e-5 dB. ``time_to_peak_s``: from the ``align`` call to TRACKING;
    ``final_loss_db``: mean over the first 20 ms of TRACKING; per switch cycle the loss
    over the last 10 ms of the on time and the 10-90 % rise of the measured power.
    """
    link = OpticalLink.from_params(node_params(params, 'simulated_actuator'))
    loss = np.asarray(link.loss_db(t, y), float)
    period = 1.0 / rate_hz
    n_win, n_lvl = int(round(LOSS_WINDOW_S * rate_hz)), int(round(LEVEL_S * rate_hz))
    out = {'states': [[int(k), st.get('state')] for k, st in states],
           'state': states[-1][1].get('state') if states else None,
           'fault_reason': states[-1][1].get('fault_reason') if states else None}
    ka, kt = events.get('align'), events.get('tracking')
    if ka is not None:
        thr = next((st.get('threshold_w') for _, st in states if st.get('threshold_w')), None)
        if thr:
            lit = np.flatnonzero(np.asarray(p[ka:]) >= thr)
            out['time_to_first_light_s'] = float(lit[0] * period) if lit.size else None
    if ka is not None and kt is not None:
        out['time_to_peak_s'] = float((kt - ka) * period)
        out['final_loss_db'] = float(np.mean(loss[kt:kt + n_win]))
        peak = next((st.get('peak_samples') for k, st in states
                     if k >= kt and st.get('state') == 'TRACKING'), None)
        out['peak_samples'] = peak
    cyc = []
    for k_off, k_on, k_end in events.get('cycles', []):
        lo = float(np.mean(p[max(k_on - n_lvl, k_off):k_on]))
        hi = float(np.mean(p[max(k_end - n_lvl, k_on):k_end]))
        cyc.append({'loss_db': float(np.mean(loss[max(k_end - n_lvl, k_on):k_end])),
                    'rise_time_s': rise_time(t[k_on:k_end], p[k_on:k_end], lo, hi)})
    if cyc:
        out['cycles'] = cyc
        out['cycle_loss_max_db'] = max(c['loss_db'] for c in cyc)
        rises = [c['rise_time_s'] for c in cyc if c['rise_time_s'] is not None]
        out['switch_rise_time_max_s'] = max(rises) if rises else None
    tracking = np.zeros(t.size, bool)
    marks = [(int(k), st.get('state')) for k, st in states] + [(t.size, None)]
    for (k0, s0), (k1, _) in zip(marks[:-1], marks[1:]):
        if s0 == 'TRACKING':
            tracking[k0:k1] = True
    if tracking.any():
        out['tracking_max_loss_db'] = float(np.max(loss[tracking]))
    return out


def format_summary(s):
    """Return the run summary as Markdown text (um, ms, dB for people)."""
    lines = ['', '## bringup summary', '', '| item | value |', '|---|---|']
    for k in ('scenario', 'controller', 'sync_mode', 'rate_hz', 'composed', 'namespace',
              'model_file', 'startup_s', 'run_wall_s', 'samples', 'stop_s', 'record', 'error'):
        if s.get(k) not in (None, ''):
            v = s[k]
            lines.append('| %s | %s |' % (k, '%.3g' % v if isinstance(v, float) else v))
    for k, v in sorted(s.get('metrics', {}).items()):
        if not isinstance(v, (int, float)) or v is None:
            continue
        if k.endswith('_m'):
            lines.append('| %s | %.4g um |' % (k[:-2], v * 1e6))
        elif k.endswith('_s'):
            lines.append('| %s | %.4g ms |' % (k[:-2], v * 1e3))
        elif k.endswith('_v'):
            lines.append('| %s | %.4g V |' % (k[:-2], v))
        else:
            lines.append('| %s | %.4g |' % (k, v))
    al = s.get('align', {})
    for k in ('state', 'fault_reason', 'time_to_first_light_s', 'time_to_peak_s',
              'final_loss_db', 'peak_samples', 'cycle_loss_max_db', 'switch_rise_time_max_s',
              'tracking_max_loss_db'):
        v = al.get(k)
        if v in (None, ''):
            continue
        if k.endswith('_s'):
            lines.append('| align %s | %.4g ms |' % (k[:-2], v * 1e3))
        elif k.endswith('_db'):
            lines.append('| align %s | %.4f dB |' % (k[:-3], v))
        else:
            lines.append('| align %s | %s |' % (k, v))
    for node, counts in sorted(s.get('sent', {}).items()):
        if not counts:
            continue
        lines.append('| sent by %s | %s |' % (node, ', '.join(
            '%s=%s' % kv for kv in sorted(counts.items()))))
    if s.get('recorded'):
        lines.append('| recorded | %s |' % ', '.join(
            '%s=%s' % kv for kv in sorted(s['recorded'].items())))
    return '\n'.join(lines)


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


if __name__ == '__main__':
    main()
