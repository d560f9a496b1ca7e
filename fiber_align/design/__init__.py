# SPDX-License-Identifier: Apache-2.0
"""
Design model of the trapezoidal piezo bimorph: statics, blocked force, modes, sweeps.

Public API (SI units):

- :func:`load_actuator` ``(path='actuator.yaml') -> Actuator``
- :func:`dynamics` ``(actuator) -> dict(alpha_m_per_v, omega_n_rad_s, first_mode_hz,
  stiffness_n_per_m, modal_mass_kg)``; :func:`design_dynamics` ``(actuator) ->
  (omega_n_rad_s, alpha_m_per_v)``, the mode the plant and the controllers share
- :func:`report` ``(actuator, voltage) -> dict`` (everything the ``design`` CLI prints)
- :func:`blocked_force`, :func:`tip_displacement`, :func:`deflection`
"""

from fiber_align.design.analysis import blocked_force, deflection_fe, dynamics, report
from fiber_align.design.mode import design_dynamics
from fiber_align.design.model import (Actuator, deflection, load_actuator,
                                      tip_compliance, tip_displacement)

__all__ = ['Actuator', 'blocked_force', 'deflection', 'deflection_fe', 'design_dynamics',
           'dynamics', 'load_actuator', 'report', 'tip_compliance', 'tip_displacement']
