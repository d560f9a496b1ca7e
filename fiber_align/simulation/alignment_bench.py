# SPDX-License-Identifier: Apache-2.0
"""
The offline alignment bench: a closed loop, the optics and the sequencer, period by period.

One control period ``k`` (docs/CONTRACTS.md): the loop's measurement ``y_k`` (m) and the
detector reading ``P_k`` (W, from the true tip position at ``t_k``) go to
``Sequencer.update(t_k, y_k, P_k)``, whose setpoint ``r_k`` (m) drives the loop for one
period. Loops: :class:`CompositeLoop` (the control core's plant, compensator, feedback
and driver, stepped by :class:`fiber_align.simulation.loop.ClosedLoop`) or
:class:`FirstOrderLoop` (a fast first-order stand-in for tests). SI units throughout.
"""

import math

import numpy as np

from fiber_align.alignment import sequencer as sq
from fiber_align.alignment.states import FAULT, PEAKING, TRACKING
from fiber_align.config import load_params
from fiber_align.control.driver import DriverCore
from fiber_align.plant import optics as op
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


class Record:
    """Per-period trace of a run (SI: s, m, W, dB); ``arrays()`` returns numpy arrays."""

    FIELDS = ('t', 'x', 'y', 'r', 'p', 'p_true', 'p_max', 'slot', 'state')

    def __init__(self):
        """Start empty."""
        self.rows = {k: [] for k in self.FIELDS}

    def add(self, **kw):
        """Append one period."""
        for k in self.FIELDS:
            self.rows[k].append(kw[k])

    def arrays(self):
        """Return the trace as a dict of numpy arrays; ``state`` is an object array."""
        out = {k: np.asarray(v, dtype=float) for k, v in self.rows.items() if k != 'state'}
        out['state'] = np.asarray(self.rows['state'], dtype=object)
        out['loss_db'] = op.loss_db(np.maximum(out['p_true'], 1e-30),
                                    np.maximum(out['p_max'], 1e-30))
        return out


#: What :meth:`Stepping.align_run` reports of the sequencer when the run stops.
SNAPSHOT = ('state', 'fault_reason', 'peak_samples', 'search_samples', 'iterations')


class Stepping:
    """
    A bench stepped one control period at a time (SI: s).

    A subclass has ``k`` (periods run), ``period_s``, ``seq`` (a sequencer: ``align()``,
    ``state``), ``step()`` and ``true_loss()`` (dB of the last period).
    """

    @property
    def t(self):
        """Return the time of the next period (s)."""
        return self.k * self.period_s

    def align_run(self, idle_s, max_s, loss_window_s):
        """
        Idle ``idle_s``, command ``align``, run to TRACKING or FAULT, then the loss window.

        :param max_s: the longest run after the command (s).
        :param loss_window_s: time in TRACKING over which the true loss is taken (s).
        :returns: dict: ``t_cmd`` (s), ``time_to_first_light_s`` (command to the first
            update in PEAKING, s), ``time_to_peak_s`` (command to the update that entered
            TRACKING, s; ``None`` if it did not), ``losses`` (dB, one per period of the
            window), and as they were when the run stopped (before the window): ``t_stop``
            (s) and the sequencer's ``state``, ``fault_reason``, ``peak_samples``,
            ``search_samples``, ``iterations`` (``None`` where it has none).
        """
        seq = self.seq
        self.run_until(idle_s)
        t_cmd = self.t
        seq.align()
        first = [None]

        def stop(b):
            if first[0] is None and seq.state == PEAKING:
                first[0] = b.t - b.period_s
            return seq.state in (TRACKING, FAULT)

        self.run_until(t_cmd + max_s, stop)
        out = {k: getattr(seq, k, None) for k in SNAPSHOT}
        out.update(t_cmd=t_cmd, t_stop=self.t, time_to_peak_s=None, losses=[],
                   time_to_first_light_s=None if first[0] is None else first[0] - t_cmd)
        if seq.state == TRACKING:
            out['time_to_peak_s'] = self.t - self.period_s - t_cmd
            t_end = self.t + loss_window_s
            while self.t < t_end - 1e-12 and seq.state == TRACKING:
                self.step()
                out['losses'].append(self.true_loss())
        return out

    def run_until(self, t_end, stop=None):
        """Step until ``t_end`` (s) or until ``stop(bench)`` is true; return the time (s)."""
        while self.t < t_end - 1e-12:
            self.step()
            if stop is not None and stop(self):
                break
        return self.t


class Bench(Stepping):
    """A sequencer, an optical link and a loop stepped together, one control period a call."""

    #: what a driver that holds its output drives the actuator to (m): its safe output
    safe_m = 0.0

    def __init__(self, loop, link, seq, period_s=1e-3, record=True):
        """Combine the parts; time starts at 0 s."""
        self.loop, self.link, self.seq = loop, link, seq
        #: the sequencer's ``driver_active`` (None: as its drivers published); False: the
        #: driver holds its output, the actuator goes to :attr:`safe_m`
        self.driver_active = None
        self.period_s = float(period_s)
        self.k = 0
        self.rec = Record() if record else None
        self.last = None

    def true_loss(self):
        """Return the true loss (dB) of the last period."""
        return true_loss(self)

    def step(self):
        """Run one control period; return ``(t, true position, power reading)``."""
        t = self.t
        x = self.loop.position_m
        y = self.loop.y_meas
        p = self.link.measure(t, x, self.period_s)
        r = self.seq.update(t, y, p, driver_active=self.driver_active)
        if self.rec is not None:
            c = self.link.coupling
            self.rec.add(t=t, x=x, y=y, r=r, p=p, p_true=c.power_w(t, x),
                         p_max=c.max_power_w(), slot=c.slot_position(t),
                         state=self.seq.state)
        self.last = (t, x, p)
        self.loop.step(self.safe_m if self.driver_active is False else r)
        self.k += 1
        return self.last


def true_loss(bench):
    """Return the true loss (dB) of the last period."""
    t, x, _ = bench.last
    return float(bench.link.loss_db(t, x))


def build(seed=0, loop='composite', slot_m=None, period_s=1e-3, record=True,
          seq_params=None, optics_params=None, setup=None, **optics_overrides):
    """
    Return a :class:`Bench` with the slot at ``slot_m`` (m; random in the range if None).

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
    lp.reset()
    return Bench(lp, link, seq, period_s, record)
