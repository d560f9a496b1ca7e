# SPDX-License-Identifier: Apache-2.0
"""
One control period of docs/CONTRACTS.md, the only place the loop body is written.

Per period ``k`` at ``t_k = k T`` with the measurement ``y_k`` (m) in hand::

    ff_k = compensator.step(r_k)          (V)
    fb_k = feedback.step(r_k, y_k)        (V; 0 without feedback)
    v_k  = driver.command(ff_k, fb_k, t_k)
    y_{k+1} = plant.step(v_k)

The offline run (:func:`fiber_align.simulation.simulate.run`) and the alignment
scenarios' closed loop both step a :class:`ClosedLoop`; the ROS graph runs the same
four calls in four nodes.
"""

NO_GAINS = (0.0, 0.0, 0.0)


class ClosedLoop:
    """
    Plant, compensator, feedback and driver stepped one control period at a time.

    After :meth:`step` the attributes ``ff``, ``fb``, ``v`` (V) and ``gains`` (the
    feedback's present gains, SI) are those of the period just run and ``y`` (m) is the
    new measurement.

    :param plant: ``step(v V) -> y m``, ``reset() -> y0 m``, ``x`` (true position, m).
    :param driver: :class:`~fiber_align.control.driver.DriverCore`.
    :param compensator: ``step(r m) -> V`` (``reset()``).
    :param feedback: ``step(r m, y m) -> V`` with ``gains`` and ``nan_count``, or None.
    :param period_s: control period ``T`` (s).
    """

    def __init__(self, plant, driver, compensator, feedback, period_s):
        """Keep the parts (already built from the configuration)."""
        self.plant = plant
        self.driver = driver
        self.compensator = compensator
        self.feedback = feedback
        self.period_s = float(period_s)
        self._comp_step = compensator.step
        self._fb_step = feedback.step if feedback is not None else None
        self._command = driver.command
        self._plant_step = plant.step
        self.reset()

    def reset(self):
        """Return every part to rest; take the first measurement (m) and return it."""
        for part in (self.compensator, self.feedback, self.driver):
            if part is not None:
                part.reset()
        self.k = 0
        self.ff = self.fb = self.v = 0.0
        self.gains = NO_GAINS
        self.y = self.plant.reset()
        return self.y

    def step(self, r):
        """Run one control period for the reference ``r`` (m); return ``y_{k+1}`` (m)."""
        return self.run((r,))

    def run(self, refs, record=None):
        """
        Run one control period per reference in ``refs`` (m); return the last ``y`` (m).

        :param record: None, or a mapping of lists that each period appends to: ``y``
            (the measurement the period used, m), ``x`` (the true position then, m),
            ``v``, ``ff``, ``fb`` (V) and ``gains`` (the feedback's gains after its step).
        """
        comp_step = self._comp_step
        fb_step = self._fb_step
        feedback = self.feedback
        command = self._command
        plant_step = self._plant_step
        plant = self.plant
        period = self.period_s
        k = self.k
        y = self.y
        ff = self.ff
        fb = self.fb
        v = self.v
        gains = self.gains
        if record is not None:
            y_add, x_add = record['y'].append, record['x'].append
            v_add, ff_add = record['v'].append, record['ff'].append
            fb_add, g_add = record['fb'].append, record['gains'].append
        for r in refs:
            ff = comp_step(r)
            if fb_step is None:
                fb = 0.0
            else:
                fb = fb_step(r, y)
                gains = feedback.gains
            v = command(ff, fb, k * period)
            if record is not None:
                y_add(y)
                x_add(plant.x)
                v_add(v)
                ff_add(ff)
                fb_add(fb)
                g_add(gains)
            y = plant_step(v)
            k += 1
        self.k = k
        self.y = y
        self.ff = ff
        self.fb = fb
        self.v = v
        self.gains = gains
        return y
