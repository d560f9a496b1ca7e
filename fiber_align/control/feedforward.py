# SPDX-License-Identifier: Apache-2.0
"""
Feedforward voltage from the reference: inverse PI model or a linear gain.

``Feedforward.step(r)`` takes the reference ``r`` (m) and returns a voltage (V): with a
PI model it runs the exact inverse PI model (SEED-NOTES section 4) on the (optionally
shaped) reference; without one it returns ``r * gain_v_per_m`` (the ``open-loop``
controller). References below 0 m are taken as 0 m (the actuator only moves one way).
"""

import math

from fiber_align.hysteresis.playbank import PlayBank


class Feedforward:
    """
    Reference (m) to feedforward voltage (V).

    The inverse model is stepped by :attr:`bank` (a
    :class:`~fiber_align.hysteresis.playbank.PlayBank`, same output in amortised O(1));
    :attr:`inverse` is the :class:`~fiber_align.hysteresis.pi.InversePIModel` it was
    built from and is not advanced.

    :param model: a :class:`fiber_align.hysteresis.pi.PIModel` (its inverse is used), or
        ``None`` for a linear gain.
    :param gain_v_per_m: the linear gain (V/m) used when ``model`` is None.
    :param shaper: an optional :class:`fiber_align.control.shaping.Shaper` applied to the
        reference first.
    :param lead: an optional :class:`fiber_align.control.shaping.Lead` applied before
        the shaper (cancels the shaper's and the hold's delay on smooth references).
    """

    def __init__(self, model=None, gain_v_per_m=None, shaper=None, lead=None):
        """Build the inverse model (exact) or keep the linear gain."""
        if model is None and gain_v_per_m is None:
            raise ValueError('Feedforward needs a PI model or a linear gain (V/m)')
        self.model = model
        self.inverse = model.inverse() if model is not None else None
        # the inverse PI model, stepped in amortised O(1) (fiber_align.hysteresis.playbank)
        self.bank = PlayBank.from_model(self.inverse) if model is not None else None
        self.gain_v_per_m = None if gain_v_per_m is None else float(gain_v_per_m)
        self.shaper = shaper
        self.lead = lead
        self.reset()

    def reset(self):
        """Return the inverse model, the lead and the shaper to rest."""
        if self.inverse is not None:
            self.inverse.reset()
            self.bank.reset()
        if self.shaper is not None:
            self.shaper.reset()
        if self.lead is not None:
            self.lead.reset()
        self.r_shaped = 0.0
        self.u = 0.0
        self.nan_count = 0

    def start_at(self, r):
        """
        Reset to rest, then settle at reference ``r`` (m) without a transient.

        The shaper and the lead are filled with ``r`` and the inverse model is brought
        up to ``r`` monotonically from rest (its state is then the loading curve's).
        For a compensator that is rebuilt (e.g. on a model reload) while the actuator
        holds ``r``; returns the voltage (V) for ``r``.
        """
        self.reset()
        r = max(float(r), 0.0) if math.isfinite(r) else 0.0
        if self.shaper is not None:
            self.shaper.reset(r)
        if self.lead is not None:
            self.lead.reset(r)
        self.r_shaped = r
        self.u = self.bank.step(r) if self.bank is not None else r * self.gain_v_per_m
        return self.u

    def step(self, r):
        """Return the feedforward voltage (V) for reference ``r`` (m); NaN holds the last."""
        if r - r != 0.0:            # NaN or infinite
            self.nan_count += 1
            return self.u
        if r < 0.0:
            r = 0.0
        if self.lead is not None:
            r = self.lead.step(r)
        if self.shaper is not None:
            r = self.shaper.step(r)
        self.r_shaped = r
        bank = self.bank
        u = self.u = bank.step(r) if bank is not None else r * self.gain_v_per_m
        return u
