# SPDX-License-Identifier: Apache-2.0
"""
Baseline: the classic 2-D coordinate hill climb, in the same state machine.

:class:`HillClimb2D` is a :class:`~fiber_align.alignment.sequencer2d.Sequencer2D` with the
same floor, threshold, spiral first light, settling, switch, faults and ``update`` API;
only PEAKING and TRACKING differ, so the two are measured side by side on one rig:

PEAKING
    From the first-light point, step one axis by ``initial_step_m`` while the settled power
    rises; when it falls, try the other direction (if this axis has not gained yet), then
    switch to the other axis. A full pass over both axes without a gain halves the step;
    the climb ends when the step is below ``min_step_m``.
TRACKING
    Perturb and observe, for ever: read the present point and the two points
    ``track_step_m`` either side of it along one axis, move to the best, switch axis.

Parameters: node ``hill_climb_2d`` of ``config/sequencer2d.yaml`` (plus everything of node
``alignment_sequencer_2d``). SI units: m, W, s.
"""

import numpy as np

from fiber_align.alignment import sequencer2d as s2d
from fiber_align.alignment.machine import check_params
from fiber_align.alignment.tracking import LossWatch
from fiber_align.config import load_params

CONFIG_NODE = 'hill_climb_2d'
UNIT = (np.array([1.0, 0.0]), np.array([0.0, 1.0]))


class HillClimb2D(s2d.Sequencer2D):
    """Coordinate hill climb with the sequencer's search and API (see the module docstring)."""

    def __init__(self, params=None, hill_params=None, period_s=None, **overrides):
        """
        Build from the two parameter mappings (``None``: ``config/sequencer2d.yaml``).

        :param params: ``alignment_sequencer_2d`` parameters (shared part).
        :param hill_params: ``hill_climb_2d`` parameters; ``overrides`` may name keys of
            either mapping.
        :param period_s: control period (s), as :class:`~s2d.Sequencer2D`.
        """
        base = load_params(s2d.CONFIG_FILE, CONFIG_NODE)
        self.hp = check_params(base, hill_params, {k: overrides.pop(k) for k in list(overrides)
                                                   if k in base}, 'hill_climb_2d')
        super().__init__(params, period_s, **overrides)

    def switch(self, on):
        """Switch on: back to the last point and perturb-and-observe from there; off: park."""
        ok, msg = super().switch(on)
        if ok and on and self.state == s2d.PEAKING:
            # the classic way: the tracking climb is the re-peak
            self._phase = 'goto'
            self._visit([self.aligned], lambda rows: self._start_tracking(self._t))
        return ok, msg

    def _start_peaking(self, center):
        self._enter(s2d.PEAKING)
        self._start_climb(center, self.hp['initial_step_m'])

    def _start_climb(self, center, step):
        self._phase = 'climb'
        self._step = float(step)
        self._axis, self._dir = 0, 1.0
        self._gained_axis = False      # this axis gained during its present turn
        self._gained_pass = False      # any axis gained since the last halving
        self._tried_back = False
        self._here = None
        self._visit([center], self._first_reading)

    def _first_reading(self, rows):
        self._here = (self._visiting.goal.copy(), float(rows[0, 2]))
        self._probe()

    def _probe(self):
        self.iterations += 1
        cand = self._here[0] + self._dir * self._step * UNIT[self._axis]
        cand = np.minimum(np.maximum(cand, self.lo), self.hi)
        if np.allclose(cand, self._here[0], rtol=0.0, atol=1e-12):
            return self._judge(None)             # at the edge: the move is impossible
        self._visit([cand], self._judge)

    def _judge(self, rows):
        gain = 10 ** (self.hp['gain_margin_db'] / 10.0)
        if rows is not None and rows[0, 2] > self._here[1] * gain:
            self._here = (self._visiting.goal.copy(), float(rows[0, 2]))
            self._gained_axis = self._gained_pass = True
            return self._probe()                 # keep going this way
        if not self._gained_axis and not self._tried_back:
            self._dir, self._tried_back = -self._dir, True
            return self._probe()
        # this axis is done for now: the other one
        self._axis = 1 - self._axis
        self._gained_axis, self._tried_back, self._dir = False, False, 1.0
        if self._axis == 0:
            if not self._gained_pass:
                self._step *= 0.5
            self._gained_pass = False
        if self._step < self.hp['min_step_m']:
            return self._finish()
        if self.iterations > 40 * int(self.p['max_iterations']):
            return self._fault('peak search did not converge: hill climb still moving '
                               'after %d probes' % self.iterations)
        self._probe()

    def _finish(self):
        here = self._here[0]
        edge = [a for a in range(2) if here[a] <= self.lo[a] or here[a] >= self.hi[a]]
        if not edge:
            return self._accept()
        # ended at an edge: one probe a full step inwards tells a peak just inside (the
        # power falls by at most k s^2) from one beyond the edge (k (s^2 + 2 s tol) or more)
        a = edge[0]
        s = self.hp['initial_step_m']
        inward = np.where(here[a] <= self.lo[a], 1.0, -1.0) * s * UNIT[a]
        self._edge_axis = a
        self._visit([here + inward], self._edge_check)

    def _edge_check(self, rows):
        a, s, tol = self._edge_axis, self.hp['initial_step_m'], self.p['range_tolerance_m']
        drop = np.log(self._here[1] / max(rows[0, 2], 1e-300))
        if drop > self.curvature_prior * (s * s + 2.0 * s * tol):
            here = self._here[0]
            return self._fault('target out of reach in %s: the hill climb ends at the edge, '
                               '%.1f um, and the power falls %.1f dB a step inwards '
                               '(reachable %.1f..%.1f um)'
                               % (s2d.AXES[a], here[a] * 1e6, 10 * drop / np.log(10),
                                  self.lo[a] * 1e6, self.hi[a] * 1e6))
        self._accept()

    def _accept(self):
        self.aligned = self._here[0].copy()
        self.aligned_power_w = self._here[1]
        self._start_tracking(self._t)

    def _start_tracking(self, t):
        self._enter(s2d.TRACKING)
        p = self.p
        self._loss = LossWatch(self.aligned_power_w, p['track_loss_db'],
                               p['track_loss_timeout_s'])
        self._axis = 0
        self._track_round()

    def _track_round(self):
        c, d = self.aligned, self.hp['track_step_m'] * UNIT[self._axis]
        self._visit([c, c + d, c - d], self._track_judge)

    def _track_judge(self, rows):
        best = int(np.argmax(rows[:, 2]))
        self.aligned = self._visiting.points[best].copy()
        self._axis = 1 - self._axis
        self._track_round()

    def _do_tracking(self, t, pos, pw):
        if self._loss.lost(t, pw):
            if self._loss.fault:
                self._fault(self._loss.fault)
            return
        self._do_visit(t, pos, pw)
