# SPDX-License-Identifier: Apache-2.0
"""``bringup``: start the fiber_align graph, run a scenario, record, stop, summarise.

Each node runs as its own process (``python -m fiber_align.nodes.<name> --ros-args
--params-file ...``) from one composed params file: the per-area files (plant, optics,
controller, compensator, driver) overlaid by ``config/fiber_align.yaml`` and any
``--params-file`` given here, written to one temporary file with ROS-compatible types.
``--composed`` runs every node in this process on one executor instead.

Sequence: start the recorder (``--record DIR``) and the nodes; wait until every node is
on the graph; configure and activate ``actuator_driver`` through
``lifecycle_msgs/srv/ChangeState``; wait until the control topics are matched; start the
plant (``run`` service); run the scenario: in this process a scenario runner publishes
exactly one ``setpoint`` (m) per ``displacement`` sample, computed from the sample's
stamp (r_k = reference(t_k), clamped to what the plant can reach, as the offline
simulation does); ``align`` starts ``alignment_sequencer`` and calls its ``align``
service instead. Then hold the plant, stop every process (SIGINT, SIGKILL after
``stop_timeout_s``), the recorder last, and print the run's metrics.

SIGINT or SIGTERM to bringup at any point runs the same clean stop. Exit code 0 on a
clean run, 1 on a failure (a node died, a timeout).
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

from fiber_align.config import config_path, read_yaml

NODES = ('simulated_actuator', 'hysteresis_compensator', 'fuzzy_pid_controller',
         'actuator_driver')
AREA_FILES = ('plant.yaml', 'optics.yaml', 'controller.yaml', 'compensator.yaml',
              'driver.yaml')
GRAPH_FILE = 'fiber_align.yaml'
SCENARIOS = ('none', 'step', 'sine', 'triangle', 'hysteresis-experiment', 'align')
#: controller names, as in ``fiber-align simulate``
CONTROLLERS = ('composite', 'composite-pid', 'fuzzy', 'pid', 'feedforward', 'open-loop')
SENT_PREFIX = 'FIBER_ALIGN_SENT '


class BringupError(RuntimeError):
    """The graph could not be brought up or failed while running."""


def _merge(a, b):
    out = dict(a)
    for k, v in b.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def compose_params(extra_files=(), overrides=None):
    """Return the merged params mapping ``{node: {ros__parameters: ...}}`` of the graph.

    :param extra_files: user params files applied last.
    :param overrides: ``{node or '/**': {name: value}}`` applied after the files.
    """
    from fiber_align.nodes._common import normalize
    data = {}
    for f in list(AREA_FILES) + [GRAPH_FILE] + list(extra_files):
        try:
            p = config_path(f)
        except Exception:  # noqa: BLE001 - optional area files (e.g. optics)
            if f in AREA_FILES:
                continue
            raise
        data = _merge(data, read_yaml(p))
    for node, params in (overrides or {}).items():
        data = _merge(data, {node: {'ros__parameters': params}})
    return normalize(data)


def node_params(data, node):
    """Return the effective parameters of ``node`` in a composed mapping (``/**`` first)."""
    out = dict(data.get('/**', {}).get('ros__parameters', {}))
    out.update(data.get(node, {}).get('ros__parameters', {}))
    return out


class Reference:
    """Setpoint source of a scenario: ``value(t)`` (m) for a sample time ``t`` (s)."""

    def __init__(self, name, reach_m):
        """Use the scenario generator of the control core; clamp to [0, reach_m] (m)."""
        from fiber_align.control import scenarios
        self.scenario = scenarios.make(name)
        self.reach = float(reach_m)

    def value(self, t):
        """Return the clamped reference (m) at ``t`` (s)."""
        r = self.scenario.reference(t)
        return min(max(r, 0.0), self.reach)


class Runner:
    """The bringup's own ROS node: orchestration, scenario runner and trace recorder."""

    def __init__(self, namespace, reference, lockstep, rate_hz):
        """Create the node, its clients and the scenario transport."""
        from lifecycle_msgs.srv import ChangeState, GetState
        from rclpy.node import Node
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64
        from std_srvs.srv import SetBool

        from fiber_align.nodes._common import CONTROL_QOS
        self.node = Node('bringup', namespace=namespace or None)
        self.ns = self.node.get_namespace().rstrip('/')
        self.reference = reference
        self.lockstep = lockstep
        self.period = 1.0 / rate_hz
        self.Float64 = Float64
        self.pub_sp = self.node.create_publisher(Float64, 'setpoint', CONTROL_QOS)
        self.node.create_subscription(JointState, 'displacement', self._on_disp, CONTROL_QOS)
        self.node.create_subscription(Float64, 'drive_voltage', self._on_drive, CONTROL_QOS)
        self.change = self.node.create_client(ChangeState, 'actuator_driver/change_state')
        self.get_state = self.node.create_client(GetState, 'actuator_driver/get_state')
        self.run_cli = self.node.create_client(SetBool, 'simulated_actuator/run')
        self.active = False          # publish setpoints
        self.t0 = None
        self.duration = math.inf
        self.done = threading.Event()
        self.t, self.r, self.y, self.v = [], [], [], []
        self.n_sp = 0
        self.lock = threading.Lock()

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
        if self.reference is not None:
            r = self.reference.value(t)
            self.pub_sp.publish(self.Float64(data=r))
            self.n_sp += 1
        else:
            r = math.nan
        with self.lock:
            self.t.append(t)
            self.r.append(r)
            self.y.append(y)

    def _on_drive(self, msg):
        with self.lock:
            self.v.append(msg.data)

    def call(self, client, request, timeout):
        """Call a service with a bounded wait; return the response."""
        if not client.wait_for_service(timeout_sec=timeout):
            raise BringupError('service %s not available within %g s'
                               % (client.srv_name, timeout))
        fut = client.call_async(request)
        end = time.monotonic() + timeout
        while not fut.done():
            if time.monotonic() > end:
                raise BringupError('service %s did not answer within %g s'
                                   % (client.srv_name, timeout))
            time.sleep(0.005)
        return fut.result()

    def wait_nodes(self, names, timeout, alive=lambda: None):
        """Wait until every node in ``names`` is on the graph (bounded)."""
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
        """Wait until each ``topic`` has at least ``(pubs, subs)`` endpoints (bounded)."""
        end = time.monotonic() + timeout
        while True:
            alive()
            short = []
            for topic, (np_, ns_) in topics.items():
                name = self.node.resolve_topic_name(topic)
                if self.node.count_publishers(name) < np_ or \
                        self.node.count_subscribers(name) < ns_:
                    short.append(topic)
            if not short:
                return
            if time.monotonic() > end:
                raise BringupError('topics not connected within %g s: %s'
                                   % (timeout, ', '.join(short)))
            time.sleep(0.05)

    def set_running(self, on, timeout=5.0):
        """Start (True) or hold (False) the plant's sample clock."""
        from std_srvs.srv import SetBool
        return self.call(self.run_cli, SetBool.Request(data=bool(on)), timeout)

    def trace(self):
        """Return ``(t, r, y)`` arrays (s, m, m) of the samples seen."""
        with self.lock:
            return np.array(self.t), np.array(self.r), np.array(self.y)


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
    ap = argparse.ArgumentParser(prog='bringup', description=__doc__.split('\n')[0])
    ap.add_argument('--scenario', choices=SCENARIOS, default=None,
                    help='scenario to run (default: bringup.scenario of fiber_align.yaml)')
    ap.add_argument('--duration', type=float, default=None, help='scenario length (s)')
    ap.add_argument('--sync', choices=('realtime', 'lockstep'), default=None,
                    help='sample clock (default: sync_mode of fiber_align.yaml)')
    ap.add_argument('--controller', choices=CONTROLLERS, default='composite')
    ap.add_argument('--rate', type=float, default=None, help='control rate (Hz)')
    ap.add_argument('--seed', type=int, default=None, help='plant sensor-noise seed')
    ap.add_argument('--no-noise', action='store_true', help='sensor noise off')
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
    code = Bringup(a).run()
    if args is None:
        sys.exit(code)
    return code


class Bringup:
    """One bring-up: processes (or composed nodes), orchestration, stop and summary."""

    def __init__(self, args):
        """Compose the parameters and decide what runs."""
        self.args = args
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
        self.children = []
        self.nodes = []
        self.runner = None
        self.executor = None
        self.spin_thread = None
        self.tmp = tempfile.TemporaryDirectory(prefix='fiber_align_bringup_')
        self.params_file = str(Path(self.tmp.name) / 'fiber_align_params.yaml')
        with open(self.params_file, 'w', encoding='utf-8') as f:
            yaml.safe_dump(self.params, f, sort_keys=False)
        self.stopping = False
        self.summary = {}

    # -- processes ------------------------------------------------------------------
    def _ros_args(self, name):
        out = ['--ros-args', '--params-file', self.params_file]
        if self.args.namespace:
            out += ['-r', '__ns:=/' + self.args.namespace.strip('/')]
        return out

    def _spawn(self, module, name, extra=()):
        cmd = [sys.executable, '-m', module] + self._ros_args(name) + list(extra)
        self.children.append(Child(name, cmd, dict(os.environ), self.args.quiet))

    def _alive(self):
        for ch in self.children:
            if not ch.alive():
                raise BringupError('%s exited with code %s' % (ch.name, ch.proc.returncode))

    def _recorder_args(self):
        rec = ['-p', 'output:=%s' % os.path.abspath(self.args.record)]
        if self.args.storage:
            rec += ['-p', 'storage:=%s' % self.args.storage]
        return rec

    def _reach(self):
        from fiber_align.plant.actuator import SimulatedActuator
        p = node_params(self.params, 'simulated_actuator')
        keys = ('rate_hz', 'hysteresis', 'omega_n_rad_s', 'damping_ratio', 'v_min', 'v_max',
                'slew_rate_v_per_s', 'noise_rms_m', 'resolution_m', 'seed')
        return SimulatedActuator.from_params({k: p[k] for k in keys if k in p}).reachable_m()

    # -- run ------------------------------------------------------------------------
    def run(self):
        """Run the whole bring-up; return the exit code."""
        import rclpy
        from rclpy.signals import SignalHandlerOptions
        signal.signal(signal.SIGTERM, _raise_interrupt)
        rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
        code = 0
        try:
            self._start()
            self._run_scenario()
        except KeyboardInterrupt:
            print('bringup: interrupted, stopping', flush=True)
        except BringupError as exc:
            print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
            code = 1
        finally:
            try:
                self._stop()
            except KeyboardInterrupt:
                self._stop()
            self._report()
            rclpy.try_shutdown()
            self.tmp.cleanup()
        return code

    def _start(self):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        t_start = time.monotonic()
        timeout = float(self.gp.get('startup_timeout_s', 30.0))
        ref = None
        if self.scenario not in ('none', 'align', 'hysteresis-experiment'):
            ref = Reference(self.scenario, self._reach())
            if self.duration <= 0:
                self.duration = ref.scenario.duration_s
        if self.scenario == 'hysteresis-experiment':
            # open loop: the compensator is bypassed, the runner publishes the drive
            # through the controller-off path (ff = drive in V given as 'linear' gain 1)
            raise BringupError('hysteresis-experiment: use fiber-align simulate (open loop '
                               'is not wired on the graph yet)')
        self.executor = SingleThreadedExecutor()
        self.runner = Runner(self.args.namespace, ref, self.sync == 'lockstep', self.rate)
        self.executor.add_node(self.runner.node)
        if self.args.record:
            self._spawn('fiber_align.nodes.bag_recorder', 'bag_recorder',
                        self._recorder_args())
        names = list(NODES)
        if self.scenario == 'align':
            names.append('alignment_sequencer')
        if self.args.composed:
            self._compose(names)
        else:
            for n in names:
                self._spawn('fiber_align.nodes.' + n, n)
        self.spin_thread = threading.Thread(target=self._spin, daemon=True)
        self.spin_thread.start()
        all_names = names + (['bag_recorder'] if self.args.record else [])
        self.runner.wait_nodes(all_names, timeout, self._alive)
        self.runner.activate_driver(timeout)
        subs_disp = 2 + (1 if self.args.record else 0)
        want = {'displacement': (1, subs_disp), 'setpoint': (1, 2),
                'feedforward_voltage': (1, 1), 'feedback_voltage': (1, 1),
                'drive_voltage': (1, 1)}
        self.runner.wait_matched(want, timeout, self._alive)
        if self.args.record:
            time.sleep(0.3)   # the recorder's subscriptions finish matching
        self.summary['startup_s'] = time.monotonic() - t_start
        print('bringup: graph up in %.2f s (%s, %g Hz, %s, %s)'
              % (self.summary['startup_s'], self.sync, self.rate, self.args.controller,
                 'composed' if self.args.composed else 'multi-process'), flush=True)
        del rclpy

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - executor shut down at exit
            pass

    def _compose(self, names):
        import importlib
        from rclpy.executors import SingleThreadedExecutor
        classes = {'simulated_actuator': 'SimulatedActuatorNode',
                   'hysteresis_compensator': 'HysteresisCompensatorNode',
                   'fuzzy_pid_controller': 'FuzzyPidControllerNode',
                   'actuator_driver': 'ActuatorDriverNode'}
        try:
            from rclpy.experimental import EventsExecutor
            self.executor.remove_node(self.runner.node)
            self.executor = EventsExecutor()
            self.executor.add_node(self.runner.node)
        except ImportError:
            assert isinstance(self.executor, SingleThreadedExecutor)
        for n in names:
            mod = importlib.import_module('fiber_align.nodes.' + n)
            cls = getattr(mod, classes.get(n, ''), None)
            if cls is None:
                raise BringupError('%s cannot be composed' % n)
            node = cls(cli_args=self._ros_args(n))
            self.nodes.append(node)
            self.executor.add_node(node)

    def _run_scenario(self):
        r = self.runner
        if self.scenario == 'none':
            r.set_running(True)
            print('bringup: running; publish `setpoint` (m). Ctrl-C stops.', flush=True)
            while True:
                self._alive()
                time.sleep(0.1)
        r.duration = self.duration
        r.active = self.scenario != 'align'
        r.set_running(True)
        t0 = time.monotonic()
        if self.scenario == 'align':
            self._align()
        else:
            wall_limit = 60.0 + 20.0 * self.duration
            while not r.done.wait(0.1):
                self._alive()
                if time.monotonic() - t0 > wall_limit:
                    raise BringupError('scenario did not finish within %g s' % wall_limit)
        self.summary['run_wall_s'] = time.monotonic() - t0

    def _align(self):
        from std_srvs.srv import Trigger
        cli = self.runner.node.create_client(Trigger, 'align')
        res = self.runner.call(cli, Trigger.Request(), 60.0 + max(self.duration, 30.0))
        self.summary['align'] = {'success': bool(res.success), 'message': res.message}
        print('bringup: align: %s (%s)' % ('ok' if res.success else 'failed', res.message),
              flush=True)

    # -- stop -----------------------------------------------------------------------
    def _stop(self):
        if self.stopping:
            # a second interrupt: just make sure everything dies
            for ch in self.children:
                ch.wait(0.5)
            return
        self.stopping = True
        r = self.runner
        if r is not None:
            r.active = False
            try:
                if r.run_cli.service_is_ready():
                    r.set_running(False, timeout=1.0)
            except BringupError:
                pass
            time.sleep(0.2)   # in-flight messages reach their subscribers
        stop_s = float(self.gp.get('stop_timeout_s', 5.0)) if hasattr(self, 'gp') else 5.0
        nodes = [ch for ch in self.children if ch.name != 'bag_recorder']
        rec = [ch for ch in self.children if ch.name == 'bag_recorder']
        for ch in nodes:
            ch.interrupt()
        end = time.monotonic() + min(stop_s, 3.0)
        for ch in nodes:
            ch.wait(end - time.monotonic())
        if self.nodes:
            from fiber_align.nodes._common import report_sent  # noqa: F401
            self.summary['sent'] = {n.get_name(): n.sent_counts() for n in self.nodes}
        if self.executor is not None:
            self.executor.shutdown(timeout_sec=1.0)
        for n in self.nodes:
            n.destroy_node()
        for ch in rec:
            ch.interrupt()
            ch.wait(min(stop_s, 4.0))
        if r is not None:
            self.summary.setdefault('sent', {})['bringup'] = {'setpoint': r.n_sp}
            r.node.destroy_node()
        for ch in self.children:
            if ch.sent is not None:
                self.summary.setdefault('sent', {})[ch.name] = ch.sent

    def _report(self):
        s = self.summary
        s.update({'scenario': self.scenario, 'sync_mode': self.sync, 'rate_hz': self.rate,
                  'controller': self.args.controller, 'composed': bool(self.args.composed),
                  'record': os.path.abspath(self.args.record) if self.args.record else None})
        r = self.runner
        if r is not None:
            t, ref, y = r.trace()
            s['samples'] = int(t.size)
            if t.size > 2 and self.scenario in ('step', 'sine', 'triangle'):
                s['metrics'] = scenario_metrics(self.scenario, t, ref, y)
            if self.args.trace and t.size:
                np.savetxt(self.args.trace, np.column_stack([t, ref, y]), delimiter=',',
                           header='t_s,r_m,y_m', comments='')
        print(format_summary(s), flush=True)
        if self.args.summary:
            with open(self.args.summary, 'w', encoding='utf-8') as f:
                json.dump(s, f, indent=1, default=str)


def scenario_metrics(name, t, r, y):
    """Return step or tracking metrics (SI) of the measured trace."""
    from fiber_align.analysis.metrics import step_metrics, tracking_metrics
    from fiber_align.control import scenarios
    sc = scenarios.make(name)
    out = {}
    if name == 'step':
        out.update(step_metrics(t, y, r[-1]))
        skip = 0.5 * (t[-1] - t[0])
    else:
        skip = sc.skip_s if t[-1] > sc.skip_s else 0.0
    out.update(tracking_metrics(t, r, y, skip))
    return {k: float(v) for k, v in out.items()}


def format_summary(s):
    """Return the run summary as Markdown text."""
    lines = ['', '## bringup summary', '',
             '| item | value |', '|---|---|']
    for k in ('scenario', 'controller', 'sync_mode', 'rate_hz', 'composed', 'startup_s',
              'run_wall_s', 'samples', 'record'):
        if k in s:
            v = s[k]
            lines.append('| %s | %s |' % (k, '%.3g' % v if isinstance(v, float) else v))
    for k, v in sorted(s.get('metrics', {}).items()):
        if k.endswith('_m'):
            lines.append('| %s | %.4g um |' % (k[:-2], v * 1e6))
        elif k.endswith('_s'):
            lines.append('| %s | %.4g ms |' % (k[:-2], v * 1e3))
        else:
            lines.append('| %s | %.4g |' % (k, v))
    for node, counts in sorted(s.get('sent', {}).items()):
        lines.append('| sent by %s | %s |' % (node, ', '.join(
            '%s=%s' % kv for kv in sorted(counts.items()))))
    if 'align' in s:
        lines.append('| align | %s |' % s['align'])
    return '\n'.join(lines)


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


if __name__ == '__main__':
    main()
