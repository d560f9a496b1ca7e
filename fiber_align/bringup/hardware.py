# SPDX-License-Identifier: Apache-2.0
"""
``bringup --hardware``: the sensorless bench graph on a real or emulated MDT693B + PM100.

``hardware:=true``'s graph (``--rig``, ``--array``: :mod:`fiber_align.graph.hardware_rig`);
``--emulate`` starts ``fiber-align emulate`` first and asks it for its ``truth`` after
the hold. Steps and exit codes: docs/hardware.md.
"""

import json
import time

from fiber_align.bringup import interrupt
from fiber_align.bringup.cli import graph
from fiber_align.bringup.harness import Harness, session
from fiber_align.bringup.observer import BringupError, Refused
from fiber_align.graph.hardware import emulator_priority
from fiber_align.graph.hardware_rig import HARDWARE_ARRAY, HARDWARE_RIG
from fiber_align.graph.params import LIFECYCLE_MANAGER
from fiber_align.hardware.errors import DeviceError
from fiber_align.hardware.process import (emulator_options, emulator_truth, start_emulator,
                                          stop_process)
from fiber_align.nodes.ros.qos import REALTIME_QOS

#: Bounds (s, wall) of the steps; the align bound is the issue's 3 s goal plus margin.
FLOOR_WAIT_S = 0.3
ALIGN_TIMEOUT_S = 10.0


class HardwareRun(Harness):
    """
    A hardware graph on the :class:`~fiber_align.bringup.harness.Harness`, and its steps.

    :param graph: a graph of ``hardware:=true`` (``build_hardware``, ``build_hardware_rig``);
        :attr:`driver`: the lifecycle node that owns the amplifier.
    :param quiet: do not relay the children's output.
    """

    def __init__(self, graph, quiet=True):
        """Write the params file; nothing starts until :meth:`start`."""
        super().__init__(graph, dict(streams={'p': 'optical_power'}, qos=REALTIME_QOS), quiet)
        self.driver = graph.managed_nodes[0]
        self._failed, self._starting = None, False

    @property
    def status(self):
        """Return the newest ``alignment_state`` (dict)."""
        return self.obs.status if self.obs is not None else {}

    @property
    def power(self):
        """Return ``(monotonic s, W)`` of every ``optical_power`` reading."""
        with self.obs.lock:
            return list(zip(self.obs.stamps['p'], self.obs.data['p']))

    @property
    def diag(self):
        """Return node -> ``(level, message)`` of its newest ``/diagnostics``."""
        return {n: (v['level'], v['message']) for n, v in dict(
            self.obs.watch.latest if self.obs else {}).items()}

    def start(self):
        """Start the graph; wait until it is ready to align (the meter reading, IDLE)."""
        self._starting = True
        try:
            super().start(ready=self._ready)
        finally:
            self._starting = False
        time.sleep(FLOOR_WAIT_S)          # the sequencer's floor readings (IDLE)
        # again: a driver tripped by a late first input refuses align until it cleared
        self.wait(self._ready, float(self.gp['startup_timeout_s']), 'the graph ready')

    def alive(self):
        """Raise when a process exited, or (starting) when the driver's start-up failed."""
        super().alive()
        if self._starting and self.obs is not None:
            # a refused configure ends the start at once with its reason, not after the
            # wait for active lifecycle nodes has run out
            self._ready()

    def _ready(self):
        """Return True when the graph can align; raise when the start-up failed."""
        if self.obs.watch.level(LIFECYCLE_MANAGER) == 2:
            # the driver sends its own reason at once; this process may read /diagnostics
            # late on a loaded machine, so it waits a few seconds for it
            self._failed = self._failed or time.monotonic()
            if self.obs.watch.level(self.driver) != 2 and time.monotonic() - self._failed < 5.0:
                return False
            raise BringupError('%s (driver: %s)' % (self.diag[LIFECYCLE_MANAGER][1],
                                                    self.diag.get(self.driver)))
        return (self.obs.watch.level(self.driver) == 0 and self.status.get('state') == 'IDLE'
                and len(self.obs.data['p']) > 5 and self.recorder_reads())

    def wait(self, cond, timeout_s, what):
        """Wait (bounded, s wall) until ``cond()``; raise :class:`BringupError` naming it."""
        self.obs.wait(cond, timeout_s, self.alive, what)

    def call(self, client, request, timeout_s=5.0):
        """Call a service (bounded); return the response."""
        return self.obs.call(client, request, timeout_s, self.alive)

    def _command(self, name, goal, timeout_s, data=None):
        """Call ``name``; return ``(ok, wall s)`` from the call to ``goal`` (or FAULT)."""
        t0, n = time.monotonic(), len(self.obs.states)
        try:
            self.obs.command(name, data, self.alive)
        except Refused:
            return False, time.monotonic() - t0
        self.wait(lambda: len(self.obs.states) > n and self.status.get('state') in (
            goal, 'FAULT'), timeout_s, goal)
        return self.status['state'] == goal, time.monotonic() - t0

    def align(self, timeout_s=ALIGN_TIMEOUT_S):
        """Call ``align``; return ``(ok, wall s)`` from the call to TRACKING (or FAULT)."""
        return self._command('align', 'TRACKING', timeout_s)

    def switch(self, on, timeout_s=ALIGN_TIMEOUT_S):
        """Switch the light off (to IDLE) or on (to TRACKING); return ``(ok, wall s)``."""
        return self._command('switch', 'TRACKING' if on else 'IDLE', timeout_s, bool(on))

    def stop(self):
        """Stop the children (the driver ramps to safe), recorder last; return exit codes."""
        s = super().stop()
        self.close()
        return {n: c['exit_code'] for n, c in s['children'].items()}


def run(args):
    """``bringup --hardware [--rig]``: run the bench as the docstring says; return the code."""
    summary, parts = {}, {}

    def steps():
        port, resource = args.port or '', args.visa_resource or ''
        if args.emulate:
            seed = args.seed if args.seed is not None else 0
            m = HARDWARE_ARRAY if args.array else HARDWARE_RIG if args.rig else None
            extra = emulator_options(seed, m and m.truth(seed), args.slot, args.meter_floor)
            parts['emu'], info = start_emulator(extra, quiet=args.quiet,
                                                priority=emulator_priority())
            port, resource = info['serial_link'], info['visa_resource']
            summary['emulator'] = info
        hw = parts['hw'] = HardwareRun(graph(args, port=port, visa_resource=resource)[0],
                                       quiet=args.quiet)
        t0 = time.monotonic()
        hw.start()
        summary['startup_s'] = time.monotonic() - t0
        ok, wall = hw.align()
        summary.update(aligned=ok, align_wall_s=wall, status=hw.status)
        try:
            cycles = summary['switch_cycles'] = []
            for _ in range((args.cycles or 0) if ok else 0):
                cycles.append([hw.switch(False), hw.switch(True)])
            ok = ok and all(a[0] and b[0] for a, b in cycles)
            t_hold = time.monotonic() + (args.hold if args.hold else float('inf'))
            while ok and time.monotonic() < t_hold and hw.status.get('state') != 'FAULT':
                hw.alive()
                time.sleep(0.05)
        except KeyboardInterrupt:
            interrupt.handled()         # aligned: Ctrl-C ends the hold
            return 0
        if hw.power:
            summary['last_power_w'] = hw.power[-1][1]
        if parts.get('emu') is not None:
            summary['truth'] = emulator_truth(parts['emu'])
        summary['final_state'] = hw.status.get('state')
        return 0 if ok and summary['final_state'] == 'TRACKING' else 1

    def stop(code):
        hw = parts.get('hw')
        if hw is not None:
            # every node's distinct ERROR messages
            summary['errors'] = hw.obs.watch.errors if hw.obs is not None else {}
            summary['exit_codes'] = hw.stop()
        if parts.get('emu') is not None:
            stop_process(parts['emu'])
        print(json.dumps(summary, default=str), flush=True)
    return session(args, summary, steps, stop, (BringupError, DeviceError, ValueError))
