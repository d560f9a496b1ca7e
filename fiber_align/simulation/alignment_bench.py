# SPDX-License-Identifier: Apache-2.0
"""
The offline alignment bench: a closed loop, the optics and the sequencer, period by period.

One control period ``k`` (docs/CONTRACTS.md): the loop's measurement ``y_k`` (m) and the
detector reading ``P_k`` (W, from the true tip position at ``t_k``) go to
``Sequencer.update(t_k, y_k, P_k)``, whose setpoint ``r_k`` (m) drives the loop for one
period. Loops: :class:`CompositeLoop` (the control core's plant, compensator, feedback
and driver, stepped by :class:`fiber_align.simulation.loop.ClosedLoop`) or
:class:`FirstOrderLoop` (a fast first-order stand-in for tests); :class:`LoopRig` makes the
loops of a machine of several axes. :class:`OneAxisBench` is the one-axis machine on the
harness of :mod:`fiber_align.simulation.harness`. SI units throughout.
"""

import math

import numpy as np

from fiber_align.alignment import sequencer as sq
from fiber_align.config import load_params
from fiber_align.control.driver import DriverCore
from fiber_align.plant import optics as op
from fiber_align.simulation import harness as hs
from fiber_align.simulation import simulate as sim
from fiber_align.simulation.loop import ClosedLoop


class FirstOrderLoop:
    """
    Stand-in closed loop: ``x <- x + (1 - exp(-T/tau)) (r - x)``, noisy sensor (SI).

    :param period_s: control period (s).
    :param tau_s: closed-loop time constant (s).
    :param noise_rms_m: sensor noise (m RMS).
    :param seed: noise seed.
    """

    name = 'ideal'

    def __init__(self, period_s=1e-3, tau_s=2e-3, noise_rms_m=10e-9, seed=0):
        """Store the constants and rest at 0 m."""
        self.period_s = float(period_s)
        self.a = 1.0 - math.exp(-self.period_s / float(tau_s))
        self.noise_rms_m = float(noise_rms_m)
        self.seed = seed
        self.reset()

    def reset(self):
        """Rest at 0 m and restart the noise."""
        self.rng = np.random.default_rng(self.seed)
        self.position_m = 0.0
        self.measure()

    def measure(self):
        """Return the sensor reading (m) of the present position."""
        self.y_meas = self.position_m + self.noise_rms_m * self.rng.standard_normal()
        return self.y_meas

    def step(self, r_m):
        """Track the setpoint ``r_m`` (m) for one period; return the new reading (m)."""
        self.position_m += self.a * (r_m - self.position_m)
        return self.measure()


class CompositeLoop:
    """
    Plant + composite controller (inverse-PI feedforward + fuzzy PID) + driver (SI).

    Built from the loaded configuration (:func:`fiber_align.simulation.simulate.make_plant`,
    :func:`~fiber_align.simulation.simulate.build_loop_parts`,
    :class:`~fiber_align.control.driver.DriverCore`); ``step(r)`` runs steps 3-6 of a
    control period for the setpoint ``r`` (m), exactly as
    :func:`fiber_align.simulation.simulate.run` does, and returns the next reading (m).

    :param period_s: control period (s).
    :param seed: plant sensor-noise seed.
    :param controller: a controller name of :mod:`fiber_align.simulation.simulate`.
    :param plant: plant kind (``default`` = dense-pi truth).
    :param model: feedforward PI model (None: identified from the plant, as simulate does).
    :param noise: sensor noise on.
    :param setup: the loaded :class:`~fiber_align.simulation.simulate.Setup` (None: read
        the files).
    """

    name = 'composite'

    def __init__(self, period_s=1e-3, seed=0, controller='composite', plant='default',
                 model=None, noise=True, setup=None):
        """Build the parts for the control rate ``1 / period_s`` (Hz)."""
        self.period_s = float(period_s)
        rate = 1.0 / self.period_s
        setup = sim.load_setup() if setup is None else setup
        self.plant = sim.make_plant(plant, rate, seed, noise, setup.plant, setup.design)
        self.driver = DriverCore.from_params(setup.driver, ramp_period_s=self.period_s)
        self.comp, self.fb = sim.build_loop_parts(controller, rate, setup, model, plant)
        self.loop = ClosedLoop(self.plant, self.driver, self.comp, self.fb, self.period_s)
        self.reach_m = self.plant.reachable_m()
        self.name = controller
        self.reset()

    def reset(self):
        """Return every part to rest; take the first reading."""
        self.y_meas = self.loop.reset()

    @property
    def position_m(self):
        """Return the true tip displacement (m)."""
        return self.plant.position_m

    def step(self, r_m):
        """Run one control period for setpoint ``r_m`` (m); return the new reading (m)."""
        self.y_meas = self.loop.step(min(max(r_m, 0.0), self.reach_m))
        return self.y_meas


def make_loop(kind='composite', period_s=1e-3, seed=0, setup=None):
    """
    Return a closed loop: ``ideal`` (stand-in) or a controller of the control core.

    :param setup: the loaded :class:`~fiber_align.simulation.simulate.Setup` for the
        control core's loop (None: read the files).
    """
    if kind == 'ideal':
        return FirstOrderLoop(period_s=period_s, seed=seed)
    return CompositeLoop(period_s=period_s, seed=seed, controller=kind, setup=setup)


class OneAxisBench(hs.Bench):
    """The one-axis machine: a loop and the fiber-to-fiber link (:mod:`.plant.optics`)."""

    POSITION, MEASURED, SETPOINT, TARGET = ('x',), ('y',), ('r',), ('slot',)
    GOAL = dict(loss_db=0.05, time_s=0.5, samples=60)
    WHERE = ('slot_m',)

    @property
    def loop(self):
        """Return the closed loop: the rig's one axis."""
        return self.rig.loops[0]

    def sense(self, t, pos):
        """Return the detector reading (W) with the core at ``pos[0]`` (m)."""
        return self.link.measure(t, pos[0], self.period_s)

    def truth(self, t, pos):
        """Return the true power, the peak power (W) and the slot position (m)."""
        c = self.link.coupling
        return c.power_w(t, pos[0]), c.max_power_w(), (c.slot_position(t),)

    def loss(self, t, pos):
        """Return the true loss in dB with the core at ``pos[0]`` (m), or at ``pos``."""
        return self.link.loss_db(t, pos[0] if np.ndim(pos) else pos)


def true_loss(bench):
    """Return the true loss (dB) of the last period."""
    return bench.true_loss()


def build(seed=0, loop='composite', slot_m=None, period_s=1e-3, record=True,
          seq_params=None, optics_params=None, setup=None, **optics_overrides):
    """
    Return a :class:`OneAxisBench` with the slot at ``slot_m`` (m; random in the range if None).

    :param loop: a loop kind of :func:`make_loop` or a loop object.
    :param setup: the loaded :class:`~fiber_align.simulation.simulate.Setup` (None: read
        the files).
    :param optics_overrides: keys of ``config/optics.yaml`` (e.g. ``fiber_broken=True``,
        ``slot_drift_m_per_s``).
    """
    sp = dict(load_params(sq.CONFIG_FILE, sq.CONFIG_NODE) if seq_params is None
              else seq_params)
    seq = sq.Sequencer(sp)
    rng = np.random.default_rng(seed)
    if slot_m is None:
        slot_m = float(rng.uniform(seq.p['range_min_m'], seq.p['range_max_m']))
    oparams = optics_params if optics_params is not None else load_params(
        op.CONFIG_FILE, op.CONFIG_NODE)
    ov = dict(optics_overrides)
    ov['slot_position_m'] = slot_m
    ov.setdefault('sample_period_s', period_s)
    link = op.OpticalLink.from_params(oparams, seed=seed + 1000, **ov)
    lp = loop if not isinstance(loop, str) else make_loop(loop, period_s, seed, setup)
    return OneAxisBench(hs.Rig((lp,), period_s), link, seq, record)


class LoopRig(hs.Rig):
    """``n`` loops of :func:`make_loop`, loop ``i`` with noise seed ``seed + i``."""

    def __init__(self, kind='composite', period_s=1e-3, seed=0, n=1):
        """Build the loops (``kind``, control period ``period_s``, s) and reset them."""
        super().__init__([make_loop(kind, period_s, seed + i) for i in range(n)], period_s,
                         seed)
