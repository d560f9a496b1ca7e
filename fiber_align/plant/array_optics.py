# SPDX-License-Identifier: Apache-2.0
"""
A fiber array against a chip's waveguides: a link per channel, three actuators in all.

Each channel is one :class:`~fiber_align.plant.link.Coupling` of :mod:`fiber_align.plant.
link`.

The array (``channels`` fibers at ``pitch_m``; channel ``i`` at ``u_i = (i - (N - 1) / 2)
pitch`` along it) sits on three actuators ``(x, y_left, y_right)`` (m), the two y ones a
lever arm ``roll_arm_m`` apart: the array's pose is ``x``, ``y = (y_left + y_right) / 2``,
``roll = atan((y_right - y_left) / roll_arm_m)`` (:func:`pose`, :func:`actuators`). With
the chip's ideal pose ``(x0, y0, roll0)`` channel ``i`` is off its waveguide by::

    dx_i = (x - x0) + u_i (cos(roll - roll0) - 1) - wx_i
    dy_i = (y - y0) + u_i sin(roll - roll0) - wy_i

(``(wx_i, wy_i)`` the waveguides' position errors, m) and couples ``a_i exp(-|d_i|^2 /
w^2)`` (``a_i`` its gain, ``w`` the mode radius ``mode_radius_m``): channel ``i`` is a
:class:`~fiber_align.plant.link.Coupling` of one facet of equal modes ``w`` and no gap
(``eta0 = 1``, curvature ``1 / w^2``), source ``P_source a_i``, its target at ``(x0 +
wx_i, y0 + wy_i)``, read at the channel's coordinates ``(x0 + dx_i + wx_i, y0 + dy_i +
wy_i)`` (:meth:`ArrayCoupling.coordinates`). Two detectors (those of ``optics.yaml``) read
the outer channels ``1`` and ``N`` (:data:`MEASURED`); the inner ones are not measured.

The objective (:func:`best_pose`): the pose that maximises the worst channel's coupling;
:func:`worst_channel_loss_db` is the loss of the worst channel at a pose against its
coupling at that best pose. Constants: ``config/array.yaml`` (node
``simulated_array_optics``). SI units: m, rad, W.
"""

import math

import numpy as np

from fiber_align.plant import link as ln
from fiber_align.plant import optics as op

CONFIG_FILE = 'array.yaml'
CONFIG_NODE = 'simulated_array_optics'
#: The array's geometry: the sequencer moves the same holder.
GEOMETRY_KEYS = ('channels', 'pitch_m', 'roll_arm_m')
ARRAY_KEYS = GEOMETRY_KEYS + ('mode_radius_m', 'chip_x_m', 'chip_y_m', 'chip_roll_rad',
                              'layout_seed', 'waveguide_offset_spread_m', 'channel_gain_spread')
SOURCE_KEYS = ('source_power_w', 'fiber_broken')
#: What a run may set instead of drawing it (one ``[wx, wy]`` and one ``a`` per channel).
LAYOUT_KEYS = ('waveguide_offsets_m', 'channel_gains')
#: The node's own keys (what it publishes), not the link's.
NODE_KEYS = ('model_period_s',)
#: The pose's labels (m, m, rad), in the order of :func:`pose`.
POSE_LABELS = ('x_m', 'y_m', 'roll_rad')


def model_labels(n):
    """
    Return the labels of :meth:`ArrayCoupling.model` for ``n`` channels (topic ``array_model``).

    The sample's time ``t_s`` (its stamp, s), the pose, the best joint pose, each
    channel's coupling (``coupling_1`` .. ``coupling_N``, 0..1 of the source power), then
    each one's at the best joint pose.
    """
    ch = tuple('coupling_%d' % (i + 1) for i in range(int(n)))
    return ('t_s',) + POSE_LABELS + tuple('best_' + k for k in POSE_LABELS) + ch + tuple(
        'best_' + k for k in ch)


def positions_along(channels, pitch_m):
    """Return ``u_i`` (m) of every channel along the array, centred on its middle."""
    n = int(channels)
    return (np.arange(n) - 0.5 * (n - 1)) * float(pitch_m)


def pose(positions_m, roll_arm_m):
    """Return the array's ``(x, y, roll)`` (m, m, rad) from ``(x, y_left, y_right)`` (m)."""
    x, yl, yr = (float(v) for v in positions_m)
    return x, 0.5 * (yl + yr), math.atan((yr - yl) / float(roll_arm_m))


def actuators(x_m, y_m, roll_rad, roll_arm_m):
    """Return ``(x, y_left, y_right)`` (m) of the pose ``(x, y, roll)`` (m, m, rad)."""
    half = 0.5 * float(roll_arm_m) * math.tan(float(roll_rad))
    return float(x_m), float(y_m) - half, float(y_m) + half


def channel_offsets(pose_, chip, u_m, offsets_m):
    """Return ``(dx, dy)`` (m, one per channel) of the array at ``pose_`` (module formula)."""
    x, y, roll = pose_
    x0, y0, roll0 = chip
    w = np.asarray(offsets_m, dtype=float).reshape(-1, 2)
    d = roll - roll0
    return (x - x0 + u_m * (math.cos(d) - 1.0) - w[:, 0],
            y - y0 + u_m * math.sin(d) - w[:, 1])


def couplings(pose_, chip, u_m, offsets_m, gains, mode_radius_m):
    """Return every channel's coupling ``a_i exp(-|d_i|^2 / w^2)`` (0..1) at ``pose_``."""
    dx, dy = channel_offsets(pose_, chip, u_m, offsets_m)
    return np.asarray(gains, dtype=float) * np.exp(-(dx * dx + dy * dy) / mode_radius_m ** 2)


def best_pose(chip, u_m, offsets_m, gains, mode_radius_m):
    """
    Return the pose ``(x, y, roll)`` that maximises the worst channel's coupling.

    The epigraph of ``max_i (|d_i|^2 / w^2 - ln a_i)`` minimised by SLSQP from the chip's
    pose (every term is convex near it: one optimum).
    """
    from scipy.optimize import minimize
    w = float(mode_radius_m)
    lna = np.log(np.asarray(gains, dtype=float))
    scale = np.array([w, w, w / max(abs(float(np.max(u_m))), w)])   # comparable steps

    def cost(z):
        dx, dy = channel_offsets(np.asarray(chip) + z[:3] * scale, chip, u_m, offsets_m)
        return (dx * dx + dy * dy) / (w * w) - lna

    z0 = np.zeros(4)
    z0[3] = float(np.max(cost(z0)))
    res = minimize(lambda z: z[3], z0, method='SLSQP',
                   constraints=[dict(type='ineq', fun=lambda z: z[3] - cost(z))],
                   options=dict(ftol=1e-14, maxiter=500))
    return tuple(float(v) for v in np.asarray(chip) + res.x[:3] * scale)


def worst_channel_loss_db(pose_, best, chip, u_m, offsets_m, gains, mode_radius_m):
    """Return the worst channel's loss (dB) at ``pose_`` against its coupling at ``best``."""
    c = couplings(pose_, chip, u_m, offsets_m, gains, mode_radius_m)
    j = int(np.argmin(c))
    ref = couplings(best, chip, u_m, offsets_m, gains, mode_radius_m)[j]
    return float(op.loss_db(c[j], ref))


def draw_layout(seed, channels, offset_spread_m, gain_spread):
    """Return ``(offsets (N, 2) m, gains (N,))`` drawn from ``seed`` (uniform, module text)."""
    rng = np.random.default_rng([int(seed), 40])
    n = int(channels)
    offsets = rng.uniform(-offset_spread_m, offset_spread_m, (n, 2))
    return offsets, rng.uniform(1.0 - gain_spread, 1.0, n)


class ArrayCoupling:
    """Noise-free power (W) of every channel against time (s) and the actuators (m)."""

    def __init__(self, source_power_w, geometry, mode_radius_m, chip, offsets_m, gains,
                 fiber_broken=False):
        """
        Store the array (SI).

        :param geometry: ``channels``, ``pitch_m``, ``roll_arm_m``.
        :param chip: the chip's ideal pose ``(x0, y0, roll0)`` (m, m, rad).
        :param offsets_m: ``(wx_i, wy_i)`` per channel (m); ``gains``: ``a_i`` (0..1).
        """
        if not mode_radius_m > 0 or int(geometry['channels']) < 2:
            raise ValueError('mode_radius_m must be > 0 and channels >= 2')
        self.n = int(geometry['channels'])
        self.pitch_m = float(geometry['pitch_m'])
        self.roll_arm_m = float(geometry['roll_arm_m'])
        self.u_m = positions_along(self.n, self.pitch_m)
        self._u = [float(u) for u in self.u_m]
        self.mode_radius_m = float(mode_radius_m)
        self.chip = tuple(float(v) for v in chip)
        self.offsets_m = np.asarray(offsets_m, dtype=float).reshape(self.n, 2)
        self.gains = np.asarray(gains, dtype=float).reshape(self.n)
        self.links = tuple(
            ln.Coupling(source_power_w * a, [ln.Facet(
                (0, 1), ln.Target((self.chip[0] + wx, self.chip[1] + wy)), self.mode_radius_m,
                self.mode_radius_m)], 1.0, fiber_broken)
            for a, (wx, wy) in zip(self.gains, self.offsets_m))
        self.source_power_w = float(source_power_w)
        self._best = self._at_best = None

    def coordinates(self, positions_m):
        """Return each channel's ``(X_i, Y_i)`` (m) on its link with the actuators there."""
        dx, dy = channel_offsets(pose(positions_m, self.roll_arm_m), self.chip, self.u_m,
                                 self.offsets_m)
        return (np.column_stack([dx, dy]) + np.asarray(self.chip[:2])
                + self.offsets_m)

    def powers_w(self, t_s, positions_m):
        """Return every channel's power (W) with the actuators at ``positions_m`` (m)."""
        return np.array([lk.power_at(t_s, tuple(c))
                         for lk, c in zip(self.links, self.coordinates(positions_m))])

    def powers_of(self, t_s, positions_m, channels):
        """
        Return the power (W) of each channel in ``channels`` (indices), scalar math.

        The per-period call: a channel's coordinates are ``(x + u_i (cos r - 1), y + u_i
        sin r)`` (the chip and waveguide terms of :meth:`coordinates` cancel), and the
        unmeasured channels are not computed (all eight took 84 us a sample).
        """
        x, y, roll = pose(positions_m, self.roll_arm_m)
        d = roll - self.chip[2]
        c, s = math.cos(d) - 1.0, math.sin(d)
        t = float(t_s)
        return tuple(self.links[i].power_at(t, (x + self._u[i] * c, y + self._u[i] * s))
                     for i in channels)

    def best(self):
        """Return the best joint pose ``(x, y, roll)`` (cached: the chip does not move)."""
        if self._best is None:
            self._best = best_pose(self.chip, self.u_m, self.offsets_m, self.gains,
                                   self.mode_radius_m)
        return self._best

    def model(self, t_s, positions_m):
        """
        Return what the model predicts with the actuators at ``positions_m`` (m).

        In the order of :func:`model_labels`: ``t_s`` (s), the pose, the best joint pose
        (m, m, rad), then every channel's coupling (0..1) at this pose and at the best pose.
        """
        now = pose(positions_m, self.roll_arm_m)
        if self._at_best is None:
            self._at_best = [float(c) for c in couplings(
                self.best(), self.chip, self.u_m, self.offsets_m, self.gains,
                self.mode_radius_m)]
        c = couplings(now, self.chip, self.u_m, self.offsets_m, self.gains,
                      self.mode_radius_m)
        return [float(t_s)] + list(now) + list(self.best()) + c.tolist() + self._at_best

    def loss_at(self, t_s, positions_m):
        """Return the worst channel's loss (dB) with the actuators there, against the best."""
        return worst_channel_loss_db(pose(positions_m, self.roll_arm_m), self.best(),
                                     self.chip, self.u_m, self.offsets_m, self.gains,
                                     self.mode_radius_m)


def measured(n):
    """Return the indices of the measured channels of an ``n``-channel array: 1 and N."""
    return (0, int(n) - 1)


class ArrayLink:
    """The array's coupling and one detector per measured channel."""

    def __init__(self, coupling, detectors):
        """Combine the coupling and the detectors (one per :func:`measured` channel)."""
        self.coupling = coupling
        self.detectors = tuple(detectors)
        self.measured = measured(coupling.n)

    def measure(self, t_s, positions_m, dt_s=None):
        """Return the readings (W) of the measured channels, actuators at ``positions_m``."""
        p = self.coupling.powers_of(t_s, positions_m, self.measured)
        return tuple(d.measure(v, dt_s) for d, v in zip(self.detectors, p))

    @classmethod
    def from_params(cls, optics_params=None, array_params=None, seed=0, **overrides):
        """
        Build a link; ``overrides`` replace keys of either mapping, or set the layout.

        :param optics_params: the ``optics`` mapping of ``config/optics.yaml`` (None: load);
            only its source and detector keys are used.
        :param array_params: node ``simulated_array_optics`` (None: load).
        :param seed: the first detector's noise seed (the second's: ``seed + 1``).
        :param overrides: also ``waveguide_offsets_m`` and ``channel_gains`` (instead of
            the ones drawn from ``layout_seed``).
        """
        layout = {k: overrides.pop(k) for k in LAYOUT_KEYS if k in overrides}
        o, c = ln.sections(optics_params, array_params, CONFIG_FILE, CONFIG_NODE)
        c = {k: v for k, v in c.items() if k not in NODE_KEYS}
        ln.split_overrides(overrides, ((ARRAY_KEYS, c), (SOURCE_KEYS + ln.DETECTOR_KEYS, o)),
                           'array optics')
        missing, unknown = sorted(set(ARRAY_KEYS) - set(c)), sorted(set(c) - set(ARRAY_KEYS))
        if missing or unknown:
            raise ValueError('array optics parameters: missing %s, unknown %s'
                             % (missing or 'none', unknown or 'none'))
        offsets, gains = draw_layout(c['layout_seed'], c['channels'],
                                     c['waveguide_offset_spread_m'], c['channel_gain_spread'])
        coupling = ArrayCoupling(
            o['source_power_w'], c, c['mode_radius_m'],
            (c['chip_x_m'], c['chip_y_m'], c['chip_roll_rad']),
            layout.get('waveguide_offsets_m', offsets), layout.get('channel_gains', gains),
            bool(o.get('fiber_broken', False)))
        return cls(coupling, (ln.detector(o, seed), ln.detector(o, seed + 1)))
