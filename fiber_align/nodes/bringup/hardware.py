# SPDX-License-Identifier: Apache-2.0
"""
``bringup --hardware``: the sensorless bench graph on a real or emulated MDT693B + PM100.

The graph is :func:`fiber_align.nodes.graph_hardware.build_hardware` (the description the
hardware launch file uses too): ``alignment_sequencer``, ``hysteresis_compensator`` and
``actuator_driver`` (backend ``mdt693b``) in one process, ``power_meter``,
``lifecycle_manager`` (activates the driver) and, with ``--record``, ``bag_recorder``.
``--emulate`` first starts ``fiber-align emulate`` as a child (it dies with ``bringup``,
``PR_SET_PDEATHSIG``) and uses the ``serial_link`` and ``visa_resource`` it prints.

Sequence: start the processes; wait until the driver is active, the meter reads and the
sequencer has its floor (``floor_wait_s``); ``align`` (std_srvs/Trigger) and time it to
TRACKING; ``--cycles`` switch off/on cycles; hold TRACKING for ``--hold`` s (0: until
SIGINT); stop every child (SIGINT: the driver ramps the amplifier to the safe voltage);
print a JSON summary (align wall time, peak power, states, faults). Exit 0 when aligned,
1 on a fault or a timeout, 2 on bad input, 130 when interrupted before the end.
"""

import json
import os
import select
import subprocess
import sys
import tempfile
import threading
import time

from fiber_align.hardware.bench import emulated
from fiber_align.nodes import bag_recorder
from fiber_align.nodes._common import DIAG_QOS, node_defaults, REALTIME_QOS
from fiber_align.nodes.alignment_sequencer import STATE_QOS
from fiber_align.nodes.bringup.checks import dds_environment
from fiber_align.nodes.bringup import interrupt
from fiber_align.nodes.bringup.children import _die_with_parent, Child
from fiber_align.nodes.graph_hardware import build_hardware

#: Bounds (s, wall) of the steps; the align bound is the issue's 3 s goal plus margin.
START_TIMEOUT_S = 30.0
FLOOR_WAIT_S = 0.3
ALIGN_TIMEOUT_S = 10.0
EMULATE_TIMEOUT_S = 20.0


class HardwareError(RuntimeError):
    """A step of the hardware run failed; the message says which and why (one line)."""


def emulator_priority():
    """
    Return the ``SCHED_FIFO`` priority of the emulators: the power meter node's (its params).

    The emulators stand for devices, which answer on time whatever the host does; at the
    normal policy, beside two CPU hogs, the emulator was the one process in the
    feedforward's chain that the hogs could hold up (the graph's nodes run at this
    priority); a 0.34 s stall of that chain tripped the driver's watchdog (docs/hardware.md).
    """
    return int(node_defaults('power_meter', ('hardware.yaml',)).get('realtime_priority', 0))


def start_emulator(extra=(), quiet=True, priority=0):
    """
    Start ``fiber-align emulate`` as a child bound to this process; return ``(proc, info)``.

    :param extra: its options (``--slot``, ``--seed``, ...).
    :param priority: run it under ``SCHED_FIFO`` at this priority (1..99; 0: the normal
        policy; refused without the right to: then the normal policy).
    :returns: the Popen and the JSON line it printed (``serial_link``, ``visa_resource``).
    """
    die = _die_with_parent(os.getpid())

    def preexec():
        die()
        if priority > 0:
            try:        # before exec: every thread of the emulator inherits it
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            except (AttributeError, OSError):
                pass
    proc = subprocess.Popen([sys.executable, '-m', 'fiber_align.cli', 'emulate'] + list(extra),
                            stdout=subprocess.PIPE, stderr=None if not quiet else
                            subprocess.DEVNULL, text=True, start_new_session=True,
                            preexec_fn=preexec)
    ready, _, _ = select.select([proc.stdout], [], [], EMULATE_TIMEOUT_S)
    line = proc.stdout.readline() if ready else ''
    try:
        return proc, json.loads(line)
    except ValueError:
        stop_process(proc)
        raise HardwareError('fiber-align emulate printed no JSON line within %g s (%r)'
                            % (EMULATE_TIMEOUT_S, line.strip())) from None


def stop_process(proc, grace_s=5.0):
    """SIGINT ``proc`` (a Popen), SIGKILL after ``grace_s`` s; return its exit code."""
    if proc.poll() is None:
        proc.send_signal(2)
        try:
            proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5.0)
    return proc.returncode


class HardwareRun:
    """
    The processes of one hardware graph and an observer of its state (own rclpy context).

    :param graph: a :class:`~fiber_align.nodes.graph.Graph` from ``build_hardware``.
    :param quiet: do not relay the children's output.
    """

    def __init__(self, graph, quiet=True):
        """Write the params file; nothing starts until :meth:`start`."""
        self.graph = graph
        self.quiet = quiet
        self.tmp = tempfile.TemporaryDirectory(prefix='fiber_align_hardware_')
        self.params = graph.write_params(os.path.join(self.tmp.name, 'params.yaml'))
        self.children = []
        self.status = {}            # the newest alignment_state (dict)
        self.states = []            # (monotonic s, state) of every change
        self.diag = {}              # node -> (level, message) of its newest /diagnostics
        self.power = []             # (monotonic s, W) of optical_power
        self.ctx = self.node = self.executor = None
        self._failed = None         # monotonic s the start-up was first seen failed
        self._measured = None       # the measured topics the recorder records
        self.errors = {}            # node -> the distinct ERROR messages it reported

    # -- processes and observer ---------------------------------------------------------
    def start(self, timeout_s=START_TIMEOUT_S):
        """Start the children and the observer; wait until the graph is ready to align."""
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        env = dict(os.environ, **dds_environment())
        g = self.graph
        for p in g.processes:
            cmd = p.command(self.params, g.namespace, g.remappings, sys.executable)
            self.children.append(Child(p.name, cmd, env, self.quiet))
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, args=[])
        self.node = rclpy.create_node('hardware_observer', context=self.ctx,
                                      namespace=('/' + g.namespace) if g.namespace else None)
        self._wire()
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        threading.Thread(target=self._spin, daemon=True).start()
        self.wait(self._ready, timeout_s, 'the driver active and the meter reading')
        time.sleep(FLOOR_WAIT_S)          # the sequencer's floor readings (IDLE)

    def _ready(self):
        """Return True when the graph can align; raise when the start-up failed."""
        if self.level('lifecycle_manager') == 2:
            # the driver's own reason follows within its diagnostics period
            self._failed = self._failed or time.monotonic()
            if self.level('actuator_driver') != 2 and time.monotonic() - self._failed < 1.0:
                return False
            raise HardwareError('%s (driver: %s)' % (self.diag['lifecycle_manager'][1],
                                                     self.diag.get('actuator_driver')))
        return (self.level('actuator_driver') == 0 and 'active' in self.diag.get(
            'actuator_driver', (0, ''))[1] and self.status.get('state') == 'IDLE'
            and len(self.power) > 5 and self._recording())

    def _recording(self):
        """Return True when a recorder of the graph (if any) reads the measured topics."""
        # started late by a loaded machine, it had missed every optical_power reading of
        # a short run (two CPU hogs, a clean-clone run)
        if not any(ch.name == 'bag_recorder' for ch in self.children):
            return True
        if self._measured is None:
            rec = node_defaults(bag_recorder.NODE_NAME, bag_recorder.AREA_FILES)
            rec.update(self.graph.node_params(bag_recorder.NODE_NAME))
            self._measured = [t for t in rec.get('topics', ()) if t.lstrip('/') in (
                'optical_power', 'drive_voltage', 'drive_voltage_readback')]
        n = self.node
        return all(any(i.node_name == bag_recorder.NODE_NAME for i in
                       n.get_subscriptions_info_by_topic(n.resolve_topic_name(t)))
                   for t in self._measured)

    def _wire(self):
        from diagnostic_msgs.msg import DiagnosticArray
        from std_msgs.msg import Float64, String
        from std_srvs.srv import SetBool, Trigger
        n = self.node
        n.create_subscription(String, 'alignment_state', self._on_state, STATE_QOS)
        n.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, DIAG_QOS)
        n.create_subscription(Float64, 'optical_power',
                              lambda m: self.power.append((time.monotonic(), m.data)),
                              REALTIME_QOS)
        self.align_client = n.create_client(Trigger, 'align')
        self.switch_client = n.create_client(SetBool, 'switch')

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - the context was shut down at the stop
            pass

    def _on_state(self, msg):
        self.status = json.loads(msg.data)
        self.states.append((time.monotonic(), self.status['state']))

    def _on_diag(self, msg):
        for st in msg.status:
            lvl = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
            name = st.name.rsplit('/', 1)[-1]
            self.diag[name] = (lvl, st.message)
            if lvl >= 2 and st.message not in self.errors.setdefault(name, []):
                self.errors[name].append(st.message)    # for the summary: why a FAULT

    def level(self, node):
        """Return the newest /diagnostics level of ``node`` (None before any)."""
        return self.diag.get(node, (None, ''))[0]

    def alive(self):
        """Raise :class:`HardwareError` when a child has exited (a lost interrupt: it)."""
        interrupt.check()
        for ch in self.children:
            if not ch.alive():
                raise HardwareError('%s exited with code %s%s' % (
                    ch.name, ch.proc.returncode, ': ' + ch.last_error if ch.last_error
                    else ''))

    def wait(self, cond, timeout_s, what):
        """Wait (bounded) until ``cond()``; raise :class:`HardwareError` naming ``what``."""
        end = time.monotonic() + timeout_s
        while not cond():
            self.alive()
            if time.monotonic() > end:
                raise HardwareError('no %s within %g s (driver: %s; sequencer: %s)' % (
                    what, timeout_s, self.diag.get('actuator_driver'), self.status))
            time.sleep(0.005)

    def call(self, client, request, timeout_s=5.0):
        """Call a service (bounded); return the response."""
        if not client.wait_for_service(timeout_sec=timeout_s):
            raise HardwareError('service %s not available' % client.srv_name)
        fut = client.call_async(request)
        self.wait(fut.done, timeout_s, 'answer from %s' % client.srv_name)
        return fut.result()

    # -- the bench steps ----------------------------------------------------------------
    def _until(self, goal, timeout_s, t0):
        self.wait(lambda: self.status.get('state') in (goal, 'FAULT') and
                  self.states[-1][0] >= t0, timeout_s, goal)
        return self.status['state'] == goal, time.monotonic() - t0

    def align(self, timeout_s=ALIGN_TIMEOUT_S):
        """Call ``align``; return ``(ok, wall s)`` from the call to TRACKING (or FAULT)."""
        from std_srvs.srv import Trigger
        t0 = time.monotonic()
        res = self.call(self.align_client, Trigger.Request())
        if not res.success:
            return False, time.monotonic() - t0
        return self._until('TRACKING', timeout_s, t0)

    def switch(self, on, timeout_s=ALIGN_TIMEOUT_S):
        """Switch the light off (to IDLE) or on (to TRACKING); return ``(ok, wall s)``."""
        from std_srvs.srv import SetBool
        t0 = time.monotonic()
        if not self.call(self.switch_client, SetBool.Request(data=bool(on))).success:
            return False, time.monotonic() - t0
        return self._until('TRACKING' if on else 'IDLE', timeout_s, t0)

    def stop(self, grace_s=5.0):
        """Stop the children (SIGINT, then SIGKILL after ``grace_s``), recorder last."""
        order = sorted(self.children, key=lambda ch: ch.name == 'bag_recorder')
        for ch in order:
            ch.interrupt()
            ch.wait(grace_s)
        if self.executor is not None:
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
            import rclpy
            rclpy.try_shutdown(context=self.ctx)
            self.executor = None
        self.tmp.cleanup()
        return {ch.name: ch.proc.returncode for ch in self.children}


def graph_trial(seed, slot_m, composed=None, settle_s=0.2, timeout_s=ALIGN_TIMEOUT_S):
    """
    Align once through the hardware graph on fresh in-process emulators; return SI metrics.

    ``final_loss_db``: the mean true loss (the emulator's truth) over the first
    ``settle_s`` (s) of TRACKING, as :func:`fiber_align.hardware.bench.align_trial`;
    ``align_wall_s``: wall time (s) from the ``align`` call to TRACKING; ``v_range``: the
    lowest and highest voltage the emulated amplifier received (V).
    """
    with emulated(seed=seed, slot_position_m=slot_m) as (bench, mdt, pm):
        g = build_hardware(port=mdt.port, visa_resource=pm.resource, composed=composed)
        hw = HardwareRun(g)
        try:
            hw.start()
            ok, wall = hw.align(timeout_s)
            losses = []
            end = time.monotonic() + settle_s
            while ok and time.monotonic() < end:
                losses.append(bench.true_loss_db())
                time.sleep(0.01)
            sent = [row[3] for row in mdt.command_log]
            out = dict(seed=seed, slot_m=slot_m, aligned=ok, align_wall_s=wall,
                       status=dict(hw.status), commands=len(sent),
                       final_loss_db=sum(losses) / len(losses) if losses else None,
                       max_loss_db=max(losses) if losses else None,
                       v_range=(min(sent), max(sent)) if sent else None)
        finally:
            codes = hw.stop()
        out['exit_codes'] = codes
        return out


def run(args):
    """``bringup --hardware``: run the bench as the module docstring says; return the code."""
    emu = None
    summary = {}
    code = 1
    hw = None
    try:
        port, resource = args.port or '', args.visa_resource or ''
        if args.emulate:
            extra = ['--seed', str(args.seed if args.seed is not None else 0)]
            if args.slot is not None:
                extra += ['--slot', repr(float(args.slot))]
            emu, info = start_emulator(extra, quiet=args.quiet, priority=emulator_priority())
            port, resource = info['serial_link'], info['visa_resource']
            summary['emulator'] = info
        g = build_hardware(port=port, visa_resource=resource, namespace=args.namespace,
                           composed=args.composed, params_file=(args.params_file or [''])[-1],
                           model_file=args.model or '', record=args.record or '')
        hw = HardwareRun(g, quiet=args.quiet)
        t0 = time.monotonic()
        hw.start()
        summary['startup_s'] = time.monotonic() - t0
        ok, wall = hw.align()
        summary.update(aligned=ok, align_wall_s=wall, status=hw.status)
        cycles = []
        for _ in range((args.cycles or 0) if ok else 0):
            cycles.append([hw.switch(False), hw.switch(True)])
        summary['switch_cycles'] = cycles
        ok = ok and all(a[0] and b[0] for a, b in cycles)
        t_hold = time.monotonic() + (args.hold if args.hold else float('inf'))
        while ok and time.monotonic() < t_hold and hw.status.get('state') != 'FAULT':
            hw.alive()
            time.sleep(0.05)
        if hw.power:
            summary['last_power_w'] = hw.power[-1][1]
        summary['final_state'] = hw.status.get('state')
        code = 0 if ok and summary['final_state'] == 'TRACKING' else 1
    except KeyboardInterrupt:
        interrupt.handled()
        code = 130 if not summary.get('aligned') else 0
    except HardwareError as exc:
        summary['error'] = str(exc)
        print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
    except ValueError as exc:           # GraphError (a ConfigError) and bad values
        summary['error'] = str(exc)
        print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
        code = 2
    finally:
        if hw is not None:
            summary['errors'] = hw.errors       # every node's distinct ERROR messages
            summary['exit_codes'] = hw.stop()
        if emu is not None:
            stop_process(emu)
    print(json.dumps(summary, default=str), flush=True)
    if getattr(args, 'summary', None):
        with open(args.summary, 'w', encoding='utf-8') as f:
            json.dump(summary, f, indent=1, default=str)
    return code
