# SPDX-License-Identifier: Apache-2.0
"""
The bimorph actuator: parameters (SI), validation and the closed-form static model.

Geometry (paper Figure 4): a five-layer cantilever PZT-5H / epoxy / beryllium bronze /
epoxy / PZT-5H clamped at ``x = 0``. The piezo layers span ``0 <= x <= L`` and their width
tapers linearly from ``A`` (base) to ``B``; the metal layer alone continues to ``x = L0``
with width ``B`` (the extension that pushes the fiber). The epoxy layers are neglected, as
in the paper (Section 3.1). Parallel electrical connection: each piezo layer sees the field
``V / hp``.

Closed-form model (paper equations 3-5, SEED-NOTES section 2), all lengths in m::

    D12   = 6 Ep hb^2 hp + 8 Ep hp^3 + 12 Ep hb hp^2 + Eb hb^3   (= 12 x bending
            stiffness per unit width, N m)
    v(x)  = 6 |d31| Ep V (hb + hp) x^2 / D12                      0 <= x <= L
    theta = 12 |d31| Ep V (hb + hp) L / D12
    v(L0) = 6 |d31| Ep V (hb + hp) (2 L0 - L) L / D12

Functions whose arguments are plain numbers or numpy arrays broadcast, so sweeps over many
geometries are single array expressions.
"""

from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from fiber_align.config import ConfigError, load_params

NODE = 'actuator'

# yaml key -> (description for messages, unit)
_POSITIVE = {
    'base_width_m': ('A, base width', 'm'),
    'tip_width_m': ('B, tip width', 'm'),
    'piezo_length_m': ('L, piezo length', 'm'),
    'total_length_m': ('L0, total length', 'm'),
    'piezo_thickness_m': ('hp, piezo layer thickness', 'm'),
    'metal_thickness_m': ('hb, metal layer thickness', 'm'),
    'piezo_modulus_pa': ('Ep, piezo Young modulus', 'Pa'),
    'metal_modulus_pa': ('Eb, metal Young modulus', 'Pa'),
    'piezo_density_kg_per_m3': ('piezo density', 'kg/m^3'),
    'metal_density_kg_per_m3': ('metal density', 'kg/m^3'),
    'max_field_v_per_m': ('largest field in a piezo layer', 'V/m'),
    'v_max': ('drive-voltage limit', 'V'),
}


@dataclass(frozen=True)
class Actuator:
    """
    Bimorph parameters, all SI; field names equal the keys of ``config/actuator.yaml``.

    Lengths in m, moduli in Pa, ``d31_m_per_v`` in m/V (its sign only sets the bending
    direction), densities in kg/m^3, ``max_field_v_per_m`` in V/m, ``v_max`` in V,
    ``tip_mass_kg`` in kg. Construction validates every value and raises
    :class:`~fiber_align.config.ConfigError` naming the field and its allowed range.
    """

    base_width_m: float
    tip_width_m: float
    piezo_length_m: float
    total_length_m: float
    piezo_thickness_m: float
    metal_thickness_m: float
    piezo_modulus_pa: float
    d31_m_per_v: float
    piezo_density_kg_per_m3: float
    metal_modulus_pa: float
    metal_density_kg_per_m3: float
    max_field_v_per_m: float
    v_max: float
    tip_mass_kg: float = 0.0
    fe_elements: int = 40
    sweep_fe_elements: int = 16
    geometry_source: str = ''

    def __post_init__(self):
        """Validate the values; raise ConfigError naming the field and the allowed range."""
        for f in fields(self):
            if f.name == 'geometry_source':
                continue
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ConfigError('%s = %r must be a finite number' % (f.name, v))
        for key, (what, unit) in _POSITIVE.items():
            v = getattr(self, key)
            if not v > 0:
                raise ConfigError('%s (%s) = %g %s is out of range; allowed: > 0 %s'
                                  % (key, what, v, unit, unit))
        if self.d31_m_per_v == 0:
            raise ConfigError('d31_m_per_v = 0 m/V is out of range; allowed: non-zero '
                              '(PZT-5H: -274e-12 m/V)')
        if self.total_length_m < self.piezo_length_m:
            raise ConfigError('total_length_m (L0) = %g m is shorter than piezo_length_m (L) = '
                              '%g m; allowed: L0 >= L' % (self.total_length_m,
                                                          self.piezo_length_m))
        if self.tip_mass_kg < 0:
            raise ConfigError('tip_mass_kg = %g kg is out of range; allowed: >= 0 kg'
                              % self.tip_mass_kg)
        for key in ('fe_elements', 'sweep_fe_elements'):
            n = getattr(self, key)
            if int(n) != n or not 4 <= n <= 2000:
                raise ConfigError('%s = %r is out of range; allowed: an integer in 4..2000'
                                  % (key, n))
            object.__setattr__(self, key, int(n))
        vf = self.field_limit_v
        if self.v_max > vf * (1 + 1e-12):
            raise ConfigError(
                'v_max = %g V exceeds the field limit: %g V/m over hp = %g m allows at most '
                '%g V; allowed: 0 < v_max <= %g V (or raise max_field_v_per_m)'
                % (self.v_max, self.max_field_v_per_m, self.piezo_thickness_m, vf, vf))

    # Short names as in the paper, in SI.
    @property
    def A(self):  # noqa: N802 - the paper's symbol
        """Return the base width A, m."""
        return self.base_width_m

    @property
    def B(self):  # noqa: N802 - the paper's symbol
        """Return the tip width B, m."""
        return self.tip_width_m

    @property
    def L(self):  # noqa: N802 - the paper's symbol
        """Return the piezo length L, m."""
        return self.piezo_length_m

    @property
    def L0(self):  # noqa: N802 - the paper's symbol
        """Return the total length L0, m."""
        return self.total_length_m

    @property
    def hp(self):
        """Return the piezo layer thickness hp, m."""
        return self.piezo_thickness_m

    @property
    def hb(self):
        """Return the metal layer thickness hb, m."""
        return self.metal_thickness_m

    @property
    def field_limit_v(self):
        """Return the largest drive voltage the field limit allows, V (max field x hp)."""
        return self.max_field_v_per_m * self.piezo_thickness_m

    def field_v_per_m(self, voltage):
        """Return the field in each piezo layer at ``voltage`` (V), V/m (parallel drive)."""
        return abs(voltage) / self.piezo_thickness_m

    def check_voltage(self, voltage, name='voltage'):
        """Raise ValueError unless ``0 <= voltage <= field limit``; return it as float (V)."""
        v = float(voltage)
        vf = self.field_limit_v
        if not np.isfinite(v) or v < 0 or v > vf * (1 + 1e-12):
            raise ValueError(
                '%s = %g V is out of range; allowed: 0..%g V (max_field_v_per_m = %g V/m '
                'over piezo_thickness_m = %g m)' % (name, v, vf, self.max_field_v_per_m,
                                                    self.piezo_thickness_m))
        return v

    def replace(self, **changes):
        """Return a validated copy with some fields changed (SI)."""
        return replace(self, **changes)

    def rectangle(self):
        """Return the rectangular counterpart: the same bimorph with constant width B."""
        return replace(self, base_width_m=self.tip_width_m)

    def as_dict(self):
        """Return the parameters as a plain dict keyed like the yaml file (SI)."""
        return asdict(self)

    def geometry(self):
        """Return the parameters as the keyword arguments of the array functions (SI)."""
        return dict(A=self.A, B=self.B, L=self.L, L0=self.L0, hp=self.hp, hb=self.hb,
                    Ep=self.piezo_modulus_pa, Eb=self.metal_modulus_pa,
                    d31=self.d31_m_per_v, rho_p=self.piezo_density_kg_per_m3,
                    rho_b=self.metal_density_kg_per_m3, tip_mass=self.tip_mass_kg)


_KEYS = [f.name for f in fields(Actuator)]
_OPTIONAL = {'tip_mass_kg', 'fe_elements', 'sweep_fe_elements', 'geometry_source'}


def load_actuator(path='actuator.yaml'):
    """
    Load an :class:`Actuator` from a ROS params file (node ``actuator``), SI units.

    :param path: a file path, or the name of a shipped file in ``config/``
        (``actuator.yaml`` = paper Table 2, ``actuator_table1.yaml`` = Table 1).
    :raises ConfigError: missing file, missing or unknown key, or a value out of range;
        the message names the file, the key and what is allowed.
    """
    params = load_params(path, node=NODE)
    where = Path(path).name
    unknown = sorted(set(params) - set(_KEYS))
    if unknown:
        raise ConfigError('%s: unknown key(s) %s in section %r; allowed keys: %s'
                          % (where, ', '.join(unknown), NODE, ', '.join(_KEYS)))
    missing = [k for k in _KEYS if k not in params and k not in _OPTIONAL]
    if missing:
        raise ConfigError('%s: missing key(s) %s in section %r'
                          % (where, ', '.join(missing), NODE))
    kwargs = {}
    for k, v in params.items():
        if k == 'geometry_source':
            kwargs[k] = str(v)
        elif isinstance(v, bool) or not isinstance(v, (int, float)):
            hint = ''
            try:
                float(v)
                hint = ' (YAML reads %s as text: write the exponent with a sign, e.g. ' \
                       '1.0e+6)' % v
            except (TypeError, ValueError):
                pass
            raise ConfigError('%s: %s = %r must be a number%s' % (where, k, v, hint))
        else:
            kwargs[k] = v
    try:
        return Actuator(**kwargs)
    except ConfigError as exc:
        raise ConfigError('%s: %s' % (where, exc)) from None


# ---------------------------------------------------------------- closed-form statics
def d12(hp, hb, Ep, Eb):  # noqa: N803 - the paper's symbols
    """
    Return D12 = 12 x the bending stiffness per unit width of the laminate, N m.

    Lengths in m, moduli in Pa; broadcasts over arrays.
    """
    return 6 * Ep * hb**2 * hp + 8 * Ep * hp**3 + 12 * Ep * hb * hp**2 + Eb * hb**3


def tip_displacement(voltage, L, L0, hp, hb, Ep, Eb, d31, **_):  # noqa: N803
    """
    Return the free output displacement at x = L0 (paper equation 5), m.

    :param voltage: drive voltage, V. Lengths in m, moduli in Pa, d31 in m/V.
    """
    return (6 * np.abs(d31) * Ep * voltage * (hb + hp) * (2 * L0 - L) * L
            / d12(hp, hb, Ep, Eb))


def deflection(x, voltage, L, L0, hp, hb, Ep, Eb, d31, **_):  # noqa: N803
    """
    Return the free deflection v(x), m, for 0 <= x <= L0 (equation 3 + rigid extension).

    :param x: positions along the beam from the clamp, m.
    :param voltage: drive voltage, V.
    """
    x = np.asarray(x, dtype=float)
    c = 6 * np.abs(d31) * Ep * voltage * (hb + hp) / d12(hp, hb, Ep, Eb)
    xp = np.minimum(x, L)
    return c * xp**2 + 2 * c * L * np.maximum(x - L, 0.0)


def tip_slope(voltage, L, hp, hb, Ep, Eb, d31, **_):  # noqa: N803
    """Return the slope theta at x = L (paper equation 4), rad."""
    return 12 * np.abs(d31) * Ep * voltage * (hb + hp) * L / d12(hp, hb, Ep, Eb)


_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)


def tip_compliance(A, B, L, L0, hp, hb, Ep, Eb, **_):  # noqa: N803
    """
    Return the static tip compliance at x = L0 of the tapered laminate, m/N.

    Unit-load method for the clamped beam: ``c = int_0^L0 (L0 - x)^2 / EI(x) dx`` with
    ``EI = b(x) D12 / 12`` on the piezo part (``b`` linear from A to B) and
    ``EI = B Eb hb^3 / 12`` on the extension. The piezo integral is done by 48-point
    Gauss-Legendre quadrature (the integrand is smooth, so this is exact to round-off);
    the extension integral is closed form. Broadcasts over arrays.
    """
    D = d12(hp, hb, Ep, Eb) / 12.0
    A, B, L, L0 = np.broadcast_arrays(*[np.asarray(a, dtype=float) for a in (A, B, L, L0)])
    s = 0.5 * (_GL_X + 1.0)                       # quadrature points on [0, 1]
    w = 0.5 * _GL_W
    xs = L[..., None] * s
    b = A[..., None] + (B - A)[..., None] * s
    piezo = L * np.sum(w * (L0[..., None] - xs) ** 2 / b, axis=-1) / D
    ext = (L0 - L) ** 3 / 3.0 / (B * Eb * hb**3 / 12.0)
    return piezo + ext
