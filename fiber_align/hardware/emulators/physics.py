# SPDX-License-Identifier: Apache-2.0
"""
The physics behind the emulators: this package's simulated bimorph, advanced in wall time.

:class:`WallClockBimorph` wraps :class:`fiber_align.plant.actuator.SimulatedActuator`
(hysteresis law, exact 2nd-order mode, amplifier clamp and slew, from
``config/plant.yaml``): the amplifier output is held between commands (zero-order hold)
and the plant is stepped every ``step_s`` (s) up to the present wall time whenever
anyone asks where the tip is. The sensor noise of the plant is not used (there is no
displacement sensor on the bench); :attr:`position_m` is the true tip position (m).

:class:`Bench` holds the three amplifier channels and the optical link
(:class:`fiber_align.plant.optics.FiberCoupling` + ``Detector``) whose input fiber
rides on one channel; the MDT693B and PM100 emulators share one Bench.
:class:`RigBench` is the two-axis rig: the input fiber rides on two bimorphs, on two
amplifier channels (``x`` and ``y`` by default), and the PM100 reads the 2-D coupling of
:mod:`fiber_align.plant.optics2d` (the simulated rig's). :class:`ArrayBench` is the fiber
array: the holder on three bimorphs (``x``, ``y_left``, ``y_right`` on channels ``x``,
``y``, ``z`` by default), the array optics of :mod:`fiber_align.plant.array_optics`, one
PM100 per outer channel (:meth:`ArrayBench.meter`).
"""

import math
import threading
import time

from fiber_align.config import load_params
from fiber_align.plant import array_optics as ao
from fiber_align.plant.actuator import SimulatedActuator
from fiber_align.plant.optics import OpticalLink
from fiber_align.plant.optics2d import OpticalLink2D

MAX_CATCH_UP_STEPS = 20000


class WallClockBimorph:
    """
    One amplifier channel driving one simulated bimorph, in wall-clock time (V, m, s).

    :param plant_params: ``simulated_actuator`` parameters (``config/plant.yaml``).
    :param v_min: amplifier lower limit (V) (the MDT693B: 0 V).
    :param v_max: amplifier upper limit (V) (the limit switch: 75, 100 or 150 V).
    :param step_s: plant step (s); the mode is discretised exactly, any step works.
    :param clock: the wall clock (s), ``time.monotonic`` by default.
    """

    def __init__(self, plant_params, v_min=0.0, v_max=100.0, step_s=1e-4,
                 clock=time.monotonic):
        """Build the plant at rest at 0 V."""
        p = dict(plant_params)
        for k in ('rate_hz', 'noise_rms_m', 'resolution_m', 'v_min', 'v_max'):
            p.pop(k, None)
        self.plant = SimulatedActuator.from_params(p, period_s=step_s, v_min=v_min,
                                                   v_max=v_max, noise_rms_m=0.0,
                                                   resolution_m=0.0)
        self.step_s = float(step_s)
        self.clock = clock
        self.v_cmd = 0.0
        self.t = clock()

    def advance(self, now=None):
        """Step the plant up to ``now`` (s) with the held command; return the position (m)."""
        now = self.clock() if now is None else now
        n = int((now - self.t) / self.step_s)
        if n > MAX_CATCH_UP_STEPS:          # long idle: the mode has long settled
            self.t += (n - MAX_CATCH_UP_STEPS) * self.step_s
            n = MAX_CATCH_UP_STEPS
        step = self.plant.step
        v = self.v_cmd
        for _ in range(max(n, 0)):
            step(v)
        if n > 0:
            self.t += n * self.step_s
        return self.plant.x

    def command(self, volts, now=None):
        """Advance to ``now``, then hold ``volts`` (V; the amplifier clamps and slews)."""
        self.advance(now)
        self.v_cmd = float(volts)

    @property
    def output_v(self):
        """Return the amplifier output voltage (V) after clamp and slew."""
        return self.plant.v_applied

    @property
    def position_m(self):
        """Return the true tip position (m) as of the last advance."""
        return self.plant.x


class Bench:
    """
    The emulated optical bench: three amplifier channels and one fiber link.

    :param plant_params: ``simulated_actuator`` parameters (``config/plant.yaml``).
    :param optics_params: ``optics`` parameters (``config/optics.yaml``).
    :param v_limit: amplifier limit switch (V).
    :param fiber_channel: channel (``x``, ``y``, ``z``) carrying the input fiber.
    :param seed: detector noise seed.
    :param step_s: plant step (s).
    :param clock: the wall clock (s).
    """

    def __init__(self, plant_params=None, optics_params=None, v_limit=100.0,
                 fiber_channel='x', seed=0, step_s=1e-4, clock=time.monotonic, **optics):
        """Build the channels at rest and the link; ``optics`` override optics keys."""
        if plant_params is None:
            plant_params = load_params('plant.yaml', 'simulated_actuator')
        if optics_params is None:
            optics_params = load_params('optics.yaml', 'simulated_actuator')
        self.clock = clock
        self.lock = threading.RLock()
        self.v_limit = float(v_limit)
        self.channels = {c: WallClockBimorph(plant_params, 0.0, self.v_limit, step_s, clock)
                         for c in ('x', 'y', 'z')}
        self.fiber_channel = fiber_channel
        link = OpticalLink.from_params(optics_params, seed=seed, **optics)
        self.coupling = link.coupling
        self.detector = link.detector
        self.t0 = clock()

    def elapsed(self, now=None):
        """Return the bench time (s) since it was built (the slot drift's time)."""
        return (self.clock() if now is None else now) - self.t0

    def command(self, channel, volts):
        """Hold ``volts`` (V) on ``channel`` from now on."""
        with self.lock:
            self.channels[channel].command(volts)

    def output_v(self, channel):
        """Return the output voltage (V) of ``channel`` now."""
        with self.lock:
            ch = self.channels[channel]
            ch.advance()
            return ch.output_v

    def advance(self):
        """Bring every channel up to now; return the fiber channel's position (m)."""
        with self.lock:
            now = self.clock()
            for ch in self.channels.values():
                ch.advance(now)
            return self.channels[self.fiber_channel].position_m

    def true_power_w(self, now=None):
        """Return the noise-free coupled power (W) now (slot at bench time)."""
        with self.lock:
            x = self.advance()
            return self.coupling.power_w(self.elapsed(now), x)

    def true_loss_db(self):
        """Return the true loss (dB) against the (moving) maximum now."""
        with self.lock:
            x = self.advance()
            return self.coupling.loss_db(self.elapsed(), x)

    def slot_position_m(self):
        """Return the slot (output core) position (m) now."""
        return self.coupling.slot_position(self.elapsed())

    def detector_sample(self, dt_s):
        """Take one raw detector sample (W) of the present power, ``dt_s`` after the last."""
        with self.lock:
            return self.detector.measure(self.true_power_w(), dt_s)

    def truth(self):
        """Return what only the emulator knows now: ``loss_db``, the true loss (dB)."""
        return dict(loss_db=self.true_loss_db())


class RigBench(Bench):
    """
    The emulated two-axis rig: three amplifier channels, the fiber on two (V, m, s, W).

    :param axes: ``{'x': channel, 'y': channel}``: the amplifier channel of each bimorph.
    :param seed: detector noise seed.
    :param optics: keys of ``optics.yaml`` and of the ``target`` of ``optics2d.yaml``
        (``position_x_m``, ``position_y_m``, ``drift_x_m_per_s``, ...).
    """

    def __init__(self, plant_params=None, optics_params=None, v_limit=100.0,
                 axes=None, seed=0, step_s=1e-4, clock=time.monotonic, **optics):
        """Build the channels at rest and the 2-D link."""
        axes = dict(axes or {'x': 'x', 'y': 'y'})
        if sorted(axes) != ['x', 'y'] or len(set(axes.values())) != 2 or not set(
                axes.values()) <= {'x', 'y', 'z'}:
            raise ValueError('axes must map x and y to two distinct channels of x, y, z, '
                             'got %r' % (axes,))
        super().__init__(plant_params, optics_params, v_limit, axes['x'], seed, step_s,
                         clock)
        self.axes = axes
        link = OpticalLink2D.from_params(optics_params, seed=seed, **optics)
        self.coupling2d = link.coupling
        self.detector = link.detector

    def advance(self):
        """Bring every channel up to now; return the fiber's ``(x, y)`` (m)."""
        with self.lock:
            now = self.clock()
            for ch in self.channels.values():
                ch.advance(now)
            return tuple(self.channels[self.axes[a]].position_m for a in ('x', 'y'))

    def true_power_w(self, now=None):
        """Return the noise-free coupled power (W) now (target at bench time)."""
        with self.lock:
            x, y = self.advance()
            return self.coupling2d.power_w(self.elapsed(now), x, y)

    def true_loss_db(self):
        """Return the true loss (dB) against the (moving) maximum now."""
        with self.lock:
            x, y = self.advance()
            return self.coupling2d.loss_db(self.elapsed(), x, y)

    def slot_position_m(self):
        """Return the target (output core) ``(x, y)`` (m) now."""
        return self.coupling2d.target.position(self.elapsed())


class ArrayBench(Bench):
    """
    The emulated fiber array: the holder on three channels, one meter per outer channel.

    :param axes: ``{'x': ch, 'y_left': ch, 'y_right': ch}``: the channel of each bimorph
        (three distinct of ``x``, ``y``, ``z``).
    :param seed: the first detector's noise seed (the second's: ``seed + 1``).
    :param optics: keys of ``optics.yaml``'s source and detector and of ``array.yaml``'s
        ``simulated_array_optics`` (``chip_x_m``, ``chip_y_m``, ``chip_roll_rad``,
        ``layout_seed``, ...).
    """

    AXES = ('x', 'y_left', 'y_right')

    def __init__(self, plant_params=None, optics_params=None, v_limit=100.0,
                 axes=None, seed=0, step_s=1e-4, clock=time.monotonic, **optics):
        """Build the channels at rest and the array's link."""
        axes = dict(axes or dict(zip(self.AXES, ('x', 'y', 'z'))))
        if sorted(axes) != sorted(self.AXES) or sorted(axes.values()) != ['x', 'y', 'z']:
            raise ValueError('axes must map x, y_left, y_right to the channels x, y, z, '
                             'got %r' % (axes,))
        super().__init__(plant_params, optics_params, v_limit, axes['x'], seed, step_s,
                         clock)
        self.axes = axes
        self.link = ao.ArrayLink.from_params(optics_params, seed=seed, **optics)
        self.array = self.link.coupling

    def advance(self):
        """Bring every channel up to now; return ``(x, y_left, y_right)`` (m)."""
        with self.lock:
            now = self.clock()
            for ch in self.channels.values():
                ch.advance(now)
            return tuple(self.channels[self.axes[a]].position_m for a in self.AXES)

    def outer_powers_w(self, now=None):
        """Return the noise-free powers (W) of the measured channels 1 and N now."""
        with self.lock:
            p = self.array.powers_w(self.elapsed(now), self.advance())
            return tuple(float(p[i]) for i in self.link.measured)

    def true_power_w(self, now=None):
        """Return the noise-free power (W) of channel 1 now."""
        return self.outer_powers_w(now)[0]

    def true_loss_db(self):
        """Return the worst channel's loss (dB) now against the best joint pose."""
        with self.lock:
            return self.array.loss_at(self.elapsed(), self.advance())

    def slot_position_m(self):
        """Return the chip's ideal pose ``(x0, y0, roll0)`` (m, m, rad)."""
        return self.array.chip

    def meter(self, j):
        """Return the reading of measured channel ``j`` (0: channel 1, 1: channel N)."""
        return _Meter(self, j)

    def truth(self):
        """
        Return the truth now (SI, dB): the pose, the best joint pose, the outer channels' loss.

        ``outer_loss_db``: each measured channel's ``10 log10(c(best) / c(now))`` with
        ``best`` the pose that maximises the worst channel's coupling
        (:func:`~fiber_align.plant.array_optics.best_pose`); ``worst_channel_loss_db``:
        :func:`~fiber_align.plant.array_optics.worst_channel_loss_db`.
        """
        a = self.array
        with self.lock:
            pos = self.advance()
        now, best = ao.pose(pos, a.roll_arm_m), a.best()
        c, ref = (ao.couplings(q, a.chip, a.u_m, a.offsets_m, a.gains, a.mode_radius_m)
                  for q in (now, best))
        return dict(positions_m=list(pos), pose=list(now), best_pose=list(best),
                    outer_loss_db=[10.0 * math.log10(ref[i] / c[i]) for i in self.link.measured],
                    worst_channel_loss_db=a.loss_at(0.0, pos))


class _Meter:
    """One measured channel of an :class:`ArrayBench`: what its PM100 emulator reads."""

    def __init__(self, bench, j):
        self.bench, self.j = bench, int(j)

    def detector_sample(self, dt_s):
        """Take one sample (W) of channel ``j``'s detector, ``dt_s`` (s) after its last."""
        with self.bench.lock:
            return self.bench.link.detectors[self.j].measure(
                self.bench.outer_powers_w()[self.j], dt_s)
