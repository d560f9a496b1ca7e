# SPDX-License-Identifier: Apache-2.0
"""
``bringup --rig``: start the two-axis rig (``graph_rig.py``), run ``align2d``, stop.

Sequence: write the rig's params file (plants held: ``autostart`` false), start its
processes (:mod:`~fiber_align.nodes.bringup.children`), wait until ``lifecycle_manager``
has both drivers active, start both plants (``x/simulated_actuator/run``,
``y/simulated_actuator/run``), let ``ALIGN_IDLE_S`` of samples pass, call ``align``, wait
for TRACKING (at most ``ALIGN_MAX_S`` of sample time), ``LOSS_WINDOW_S`` more, hold both
plants, stop every process. The observer records, per sample, both displacements, the
optical power and both setpoints (reliable, deep, transient local: every sample).

In lockstep the run is compared with the offline run of the same description
(:func:`compare_offline`: :mod:`fiber_align.simulation.alignment2d_scenarios` with the
``align`` command before the same sample): the summary's ``offline`` holds the largest
difference of each stream, and the exit code is 1 when one exceeds the tolerance.
"""

import json
import math
import os
import shutil
import sys
import tempfile
import threading
import time

import numpy as np

from fiber_align.nodes import graph_rig as gr
from fiber_align.nodes._common import CONTROL_QOS, LATCHED_QOS
from fiber_align.nodes.bringup import interrupt, summary as sm
from fiber_align.nodes.bringup.children import Child
from fiber_align.nodes.bringup.cli import parse_params
from fiber_align.nodes.bringup.observer import BringupError, Runner
from fiber_align.simulation import alignment2d_scenarios as a2

#: Streams recorded per sample: name -> (topic, message field).
STREAMS = {'mx': 'x/displacement', 'my': 'y/displacement', 'p': 'optical_power',
           'rx': 'x/setpoint', 'ry': 'y/setpoint'}
#: Lockstep equality bounds: positions and setpoints (m), power (relative). The graph
#: computes the offline run's operations on the same float64 inputs in the same order
#: (the messages carry float64), so the runs are equal to the last bit; the bounds only
#: leave room for a last-bit difference, far below any physical effect.
TOLERANCE_M = 1e-15
TOLERANCE_REL = 1e-12
#: bringup options of the 1-D graph only: (attribute, option); refused with ``--rig``.
ONE_AXIS_OPTIONS = (('scenario', '--scenario'), ('duration', '--duration'),
                    ('model', '--model'), ('rate', '--rate'), ('no_noise', '--no-noise'),
                    ('cycles', '--cycles'), ('record', '--record'), ('storage', '--storage'),
                    ('strict', '--strict'))


class RigObserver:
    """Watch the rig: per-sample streams, ``alignment_state``, service calls (SI)."""

    call = Runner.call

    def __init__(self, namespace):
        """Create the observer and client nodes, their subscriptions and clients."""
        from lifecycle_msgs.srv import GetState
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64, String
        from std_srvs.srv import SetBool, Trigger
        ns = namespace.strip('/') or None
        self.node = Node('bringup_rig', namespace=ns)
        self.cnode = Node('bringup_rig_client', namespace=ns)
        self.cexec = SingleThreadedExecutor()
        self.cexec.add_node(self.cnode)
        self.lock = threading.Lock()
        self.data = {k: [] for k in STREAMS}
        self.states = []
        for key, topic in STREAMS.items():
            typ = JointState if topic.endswith('displacement') else Float64
            self.node.create_subscription(typ, topic, self._adder(key), CONTROL_QOS)
        self.node.create_subscription(String, 'alignment_state', self._on_state, LATCHED_QOS)
        cn = self.cnode
        self.get_state = {a: cn.create_client(GetState, '%s/actuator_driver/get_state' % a)
                          for a in gr.AXES}
        self.run_cli = {a: cn.create_client(SetBool, '%s/simulated_actuator/run' % a)
                        for a in gr.AXES}
        self.align_cli = cn.create_client(Trigger, 'align')

    def _adder(self, key):
        def add(msg):
            v = msg.position[0] if hasattr(msg, 'position') else msg.data
            with self.lock:
                self.data[key].append(float(v))
        return add

    def _on_state(self, msg):
        with self.lock:
            self.states.append(json.loads(msg.data))

    @property
    def samples(self):
        """Return how many samples are complete (recorded in every stream) so far."""
        with self.lock:
            return min(len(v) for v in self.data.values())

    def state(self):
        """Return the latest ``alignment_state`` (``{}`` before the first)."""
        with self.lock:
            return dict(self.states[-1]) if self.states else {}

    def first(self, state):
        """Return the first ``alignment_state`` in ``state`` (``None`` if none)."""
        with self.lock:
            return next((dict(s) for s in self.states if s.get('state') == state), None)

    def arrays(self):
        """Return every stream, cut to the complete samples, as numpy arrays in SI units."""
        n = self.samples
        with self.lock:
            return {k: np.asarray(v[:n]) for k, v in self.data.items()}

    def wait(self, cond, wall_s, alive, what):
        """Wait (bounded, s wall) until ``cond()``; ``alive()`` may raise meanwhile."""
        end = time.monotonic() + wall_s
        while not cond():
            alive()
            if time.monotonic() > end:
                raise BringupError('%s not reached within %g s (at sample %d)'
                                   % (what, wall_s, self.samples))
            time.sleep(0.005)

    def destroy(self):
        """Destroy both nodes."""
        self.cexec.shutdown(timeout_sec=0.5)
        self.cnode.destroy_node()
        self.node.destroy_node()


def compare_offline(seed, align_sample, graph):
    """
    Run the offline ``align2d`` with ``align`` before sample ``align_sample``; compare.

    :param graph: the graph's per-sample arrays (:meth:`RigObserver.arrays`).
    :returns: dict: ``samples`` compared, ``max_abs_<stream>`` (m, W), ``max_rel_p``,
        ``equal`` (within :data:`TOLERANCE_M` / :data:`TOLERANCE_REL`), the offline
        ``state`` and ``offline_samples``.
    """
    bench = a2.build(seed=seed, record=True)
    res = a2.align_bench(bench, idle_s=align_sample * bench.period_s)
    tr = bench.trace()
    n = min(tr['t'].size, min(v.size for v in graph.values()))
    out = {'samples': int(n), 'offline_samples': int(tr['t'].size),
           'state': res['state'], 'time_to_peak_s': res['time_to_peak_s'],
           'peak_samples': res['peak_samples'], 'final_loss_db': res['final_loss_db']}
    equal = n == tr['t'].size
    for k in STREAMS:
        d = np.abs(graph[k][:n] - tr[k][:n])
        out['max_abs_' + k] = float(d.max()) if n else math.nan
        if k == 'p':
            out['max_rel_p'] = float((d / np.abs(tr[k][:n])).max()) if n else math.nan
            equal = equal and out['max_rel_p'] <= TOLERANCE_REL
        else:
            equal = equal and out['max_abs_' + k] <= TOLERANCE_M
    out['equal'] = bool(equal)
    return out


def rig_graph(a):
    """
    Return the rig's :class:`~fiber_align.nodes.graph_rig.RigGraph` for the options ``a``.

    The plants are held (``autostart`` false) until both drivers are active.

    :raises GraphError: a bad option (exit code 2).
    """
    bad = [opt for attr, opt in ONE_AXIS_OPTIONS if getattr(a, attr, None) not in (None, False)]
    if len(a.params_file) > 1:
        bad.append('a second --params-file')
    if bad:
        raise gr.g.GraphError('%s: not available with --rig' % ', '.join(bad))
    ov = parse_params(a.param, {'simulated_actuator': {'autostart': False}})
    return gr.build_rig(namespace=a.namespace or gr.RIG_NAMESPACE, composed=a.composed,
                        sync_mode=a.sync or '', controller=a.controller,
                        seed=int(a.seed or 0), params_file=(a.params_file or [''])[0],
                        overrides=ov)


def run_rig(a, g):
    """Run ``bringup --rig`` (options ``a``, graph ``g``); return the exit code."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import SetBool, Trigger
    seed = g.seed
    lockstep = g.sync_mode == 'lockstep'
    tmp = tempfile.mkdtemp(prefix='fiber_align_rig_')
    params = g.write_params(os.path.join(tmp, 'params.yaml'))
    rate = 1.0 / g.node_params(gr.SEQUENCER_2D)['control_period_s']
    summary = {'scenario': 'align2d', 'rig': True, 'sync_mode': g.sync_mode, 'seed': seed,
               'composed': g.composed, 'namespace': g.namespace, 'rate_hz': rate,
               'error': ''}
    t0 = time.monotonic()
    rclpy.init(args=[])
    children, obs, ex, spin = [], None, None, None
    code = 0
    try:
        obs = RigObserver(g.namespace)
        ex = SingleThreadedExecutor()
        ex.add_node(obs.node)
        spin = threading.Thread(target=ex.spin, daemon=True)
        spin.start()
        for p in g.processes:
            children.append(Child(p.name, p.command(params, g.namespace, g.remappings,
                                                    sys.executable), dict(os.environ),
                                  a.quiet))

        def alive():
            interrupt.check()
            dead = [ch.name for ch in children if not ch.alive()]
            if dead:
                raise BringupError('process %s exited' % ', '.join(dead))

        def active():
            from lifecycle_msgs.srv import GetState
            return all(obs.call(cl, GetState.Request(), 10.0, alive).current_state.label
                       == 'active' for cl in obs.get_state.values())
        obs.wait(active, 60.0, alive, 'both drivers active')
        # the align server discovered before the clock starts: a late discovery would
        # otherwise let the lockstep graph idle on for seconds before the command
        obs.wait(lambda: obs.align_cli.wait_for_service(timeout_sec=0.1), 30.0, alive,
                 'the align service')
        for cl in obs.run_cli.values():
            obs.call(cl, SetBool.Request(data=True), 10.0, alive)
        summary['startup_s'] = time.monotonic() - t0
        t_run = time.monotonic()
        k = int(round(sm.ALIGN_IDLE_S * rate))
        obs.wait(lambda: obs.samples >= k, 60.0, alive, 'sample %d' % k)
        res = obs.call(obs.align_cli, Trigger.Request(), 10.0, alive)
        if not res.success:
            raise BringupError('align refused: %s' % res.message)
        obs.wait(lambda: obs.state().get('align_sample') is not None, 10.0, alive,
                 'the align answer')
        k_align = obs.state()['align_sample']
        obs.wait(lambda: obs.state().get('state') in ('TRACKING', 'FAULT')
                 or obs.samples > k_align + sm.ALIGN_MAX_S * rate, 120.0, alive,
                 'TRACKING')
        tracking = obs.first(a2.s2d.TRACKING)
        if tracking is None:
            raise BringupError('alignment ended in %s: %s' % (
                obs.state().get('state'), obs.state().get('fault_reason') or 'timeout'))
        k_end = tracking['sample'] + int(round(sm.LOSS_WINDOW_S * rate)) + 5
        obs.wait(lambda: obs.samples >= k_end, 60.0, alive, 'sample %d' % k_end)
        for cl in obs.run_cli.values():
            obs.call(cl, SetBool.Request(data=False), 10.0, alive)
        summary['run_wall_s'] = time.monotonic() - t_run
        summary.update(align_sample=k_align, tracking_sample=tracking['sample'],
                       time_to_peak_s=(tracking['sample'] - 1 - k_align) / rate,
                       peak_samples=tracking['peak_samples'], state=obs.state().get('state'),
                       samples=obs.samples)
        if lockstep:
            summary['offline'] = compare_offline(seed, k_align, obs.arrays())
            # the offline run has the shipped parameters: with others it is only reported
            comparable = not (a.param or a.params_file)
            summary['offline']['comparable'] = comparable
            code = 0 if summary['offline']['equal'] or not comparable else 1
    except BringupError as exc:
        summary['error'] = str(exc)
        code = 1
    except KeyboardInterrupt:
        interrupt.handled()
        summary['error'] = 'interrupted'
        code = 130
    finally:
        for ch in children:
            ch.interrupt()
        summary['children'] = {ch.name: ch.wait(5.0) for ch in children}
        if ex is not None:
            ex.shutdown(timeout_sec=1.0)
        if spin is not None:
            spin.join(timeout=2.0)
        if obs is not None:
            if a.trace:
                write_trace(a.trace, obs.arrays(), rate)
            obs.destroy()
        rclpy.try_shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
    _report(summary, a)
    return code


def write_trace(path, arrays, rate):
    """Write ``k,t_s,mx_m,my_m,p_w,rx_m,ry_m`` of every sample (SI) to ``path``."""
    n = min(v.size for v in arrays.values())
    k = np.arange(n)
    cols = [k, k / rate] + [arrays[c][:n] for c in ('mx', 'my', 'p', 'rx', 'ry')]
    np.savetxt(path, np.column_stack(cols), delimiter=',', fmt='%.17g',
               header='k,t_s,mx_m,my_m,p_w,rx_m,ry_m', comments='')


def _report(summary, a):
    """Print the run for people (ms, um) and write ``--summary`` (JSON, SI)."""
    if a.summary:
        with open(a.summary, 'w', encoding='utf-8') as f:
            json.dump(summary, f, indent=2, sort_keys=True, default=str)
    off = summary.get('offline') or {}
    print('rig align2d (%s, seed %d): %s, align at sample %s, time to peak %s ms, peak '
          'samples %s%s' % (summary['sync_mode'], summary['seed'],
                            summary.get('state') or summary['error'],
                            summary.get('align_sample'),
                            '%.1f' % (summary['time_to_peak_s'] * 1e3)
                            if summary.get('time_to_peak_s') is not None else '-',
                            summary.get('peak_samples'),
                            '' if not off else '; offline: %d samples compared, max |dx| '
                            '%.3g m, max |dsetpoint| %.3g m, max rel dP %.3g, %s'
                            % (off['samples'], max(off['max_abs_mx'], off['max_abs_my']),
                               max(off['max_abs_rx'], off['max_abs_ry']), off['max_rel_p'],
                               'EQUAL' if off['equal'] else 'DIFFERENT')), flush=True)
