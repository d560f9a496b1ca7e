# SPDX-License-Identifier: Apache-2.0
"""
The live view's 2-D power map of the rig's search (pure: no rclpy; docs/live_view.md).

:class:`SamplePairer` pairs each power reading with the positions the realtime 2-D
sequencer pairs it with (the latest ``y`` and the power received since the previous
``x`` sample); :class:`PowerMap` keeps the brightest reading per cell;
:meth:`PowerMap.grid` is a ``foxglove.Grid`` in its JSON form (:data:`GRID_SCHEMA`),
:func:`grid_peak` its inverse; :class:`SearchMap`, the map of one search fed the rig's
raw readings, is what the live view serves. SI units (m, W); dBm only where a person
reads it.
"""

import base64
import math

import numpy as np

from fiber_align.analysis.liveview import float64_value, joint_position


class SamplePairer:
    """
    Pair readings as the realtime 2-D sequencer does.

    Each ``x`` sample is paired with the latest ``y`` and the newest power received since
    the previous ``x`` sample (none: no pair). Feed the readings in arrival order.
    """

    def __init__(self):
        """Start with nothing received."""
        self.y_m = None
        self.power_w = None

    def y(self, y_m):
        """Note a ``y`` position (m)."""
        self.y_m = float(y_m)

    def power(self, power_w):
        """Note a power reading (W)."""
        self.power_w = float(power_w)

    def x(self, x_m):
        """Return ``(x, y, power)`` (m, m, W) for an ``x`` sample (m), or ``None``."""
        p, self.power_w = self.power_w, None
        if p is None or self.y_m is None:
            return None
        return float(x_m), self.y_m, p


#: The foxglove.Grid packed field types (PackedElementField.NumericType).
FLOAT32 = 7


class PowerMap:
    """
    The brightest power reading (W) per cell of a square grid over the search range.

    Rows run along ``y``, columns along ``x``; cell ``(0, 0)`` has its lower corner at
    ``(x_min_m, y_min_m)``. A reading outside the range is not kept.

    :param x_min_m: low ``x`` edge (m); ``x_max_m``, ``y_min_m``, ``y_max_m`` likewise.
    :param cell_m: cell side (m).
    """

    def __init__(self, x_min_m, x_max_m, y_min_m, y_max_m, cell_m):
        """Size the grid; no cell is visited."""
        self.x0, self.y0, self.cell = float(x_min_m), float(y_min_m), float(cell_m)
        if not (self.cell > 0 and x_max_m > x_min_m and y_max_m > y_min_m):
            raise ValueError('power map: need x_max > x_min, y_max > y_min and cell > 0')
        self.nx = int(math.ceil((float(x_max_m) - self.x0) / self.cell - 1e-9))
        self.ny = int(math.ceil((float(y_max_m) - self.y0) / self.cell - 1e-9))
        self.power_w = np.full((self.ny, self.nx), np.nan)
        self.count = 0

    def reset(self):
        """Forget every reading (a new search)."""
        self.power_w[:] = np.nan
        self.count = 0

    def add(self, x_m, y_m, power_w):
        """Keep ``power_w`` (W) at ``(x_m, y_m)`` (m) if brighter; return True if inside."""
        if not (math.isfinite(x_m) and math.isfinite(y_m) and math.isfinite(power_w)):
            return False
        i = int(math.floor((y_m - self.y0) / self.cell))
        j = int(math.floor((x_m - self.x0) / self.cell))
        if not (0 <= i < self.ny and 0 <= j < self.nx):
            return False
        old = self.power_w[i, j]
        if not old >= power_w:
            self.power_w[i, j] = power_w
        self.count += 1
        return True

    def center(self, i, j):
        """Return the centre ``(x, y)`` (m) of the cell in row ``i``, column ``j``."""
        return self.x0 + (j + 0.5) * self.cell, self.y0 + (i + 0.5) * self.cell

    def peak(self):
        """Return ``(x, y, power)`` (m, m, W) of the brightest cell, or ``None``."""
        if not np.isfinite(self.power_w).any():
            return None
        i, j = np.unravel_index(np.nanargmax(self.power_w), self.power_w.shape)
        x, y = self.center(i, j)
        return x, y, float(self.power_w[i, j])

    def dbm(self):
        """Return the map in dBm (float32 rows along y; NaN where nothing was read)."""
        with np.errstate(divide='ignore', invalid='ignore'):
            out = 10.0 * np.log10(self.power_w / 1e-3)
        return out.astype(np.float32)

    def grid(self, stamp_ns, frame_id):
        """
        Return the map as a ``foxglove.Grid`` in Foxglove's JSON encoding (a dict).

        One float32 field ``power_dbm`` per cell; ``data`` base64, as JSON carries bytes.

        :param stamp_ns: the map's time (ns).
        :param frame_id: the frame of the map (its ``pose`` is the range's corner there).
        """
        data = self.dbm().tobytes()
        return {
            'timestamp': {'sec': int(stamp_ns // 1_000_000_000),
                          'nsec': int(stamp_ns % 1_000_000_000)},
            'frame_id': frame_id,
            'pose': {'position': {'x': self.x0, 'y': self.y0, 'z': 0.0},
                     'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0}},
            'column_count': self.nx,
            'cell_size': {'x': self.cell, 'y': self.cell},
            'row_stride': 4 * self.nx,
            'cell_stride': 4,
            'fields': [{'name': 'power_dbm', 'offset': 0, 'type': FLOAT32}],
            'data': base64.b64encode(data).decode('ascii'),
        }


class SearchMap:
    """
    The power map of one search from the rig's raw readings (the live view's map channel).

    A new search (``SEARCHING`` after another state) starts a new map; the readings are
    paired in the order of their source stamps (:class:`SamplePairer`); :meth:`due` gives
    the grid every ``period_s`` (s) once it holds a reading, and at once when asked again.

    :param cell_m: cell side (m); the range (m) as :class:`PowerMap`'s.
    """

    def __init__(self, x_min_m, x_max_m, y_min_m, y_max_m, cell_m, period_s):
        """Start an empty map, no state seen, no grid sent."""
        self.map = PowerMap(x_min_m, x_max_m, y_min_m, y_max_m, cell_m)
        self.pairer = SamplePairer()
        self.period_s = float(period_s)
        self.state = None
        self.t_sent = 0.0

    def on_state(self, state):
        """Note the sequencer's state (str); a new search starts a new map."""
        if state == 'SEARCHING' and self.state != 'SEARCHING':
            self.map.reset()
        self.state = state

    def feed(self, events):
        """Take ``(source stamp, key, CDR bytes)`` readings: key ``x``, ``y`` (m) or ``p`` (W)."""
        for _, key, data in sorted(events, key=lambda e: e[0]):
            if key == 'p':
                self.pairer.power(float64_value(data))
            elif key == 'y':
                self.pairer.y(joint_position(data))
            else:
                got = self.pairer.x(joint_position(data))
                if got is not None:
                    self.map.add(*got)

    def due(self, now, stamp_ns, resend=False):
        """
        Return the grid (:meth:`PowerMap.grid`, frame ``rig``) due at ``now`` (s), or None.

        :param stamp_ns: the grid's time (ns); :param resend: a client asked for it again.
        """
        if resend or now - self.t_sent >= self.period_s:
            self.t_sent = now
            if self.map.count or resend:
                return self.map.grid(stamp_ns, 'rig')
        return None


def grid_peak(grid):
    """
    Return ``(x, y, value)`` (m, m, field value) of the largest cell of a JSON Grid.

    The inverse of :meth:`PowerMap.grid` (one float32 field): what a client reads.
    """
    values = np.frombuffer(base64.b64decode(grid['data']), dtype='<f4')
    n = int(grid['column_count'])
    values = values.reshape(-1, n)
    if not np.isfinite(values).any():
        return None
    i, j = np.unravel_index(np.nanargmax(values), values.shape)
    c = grid['cell_size']
    p = grid['pose']['position']
    return (p['x'] + (j + 0.5) * c['x'], p['y'] + (i + 0.5) * c['y'],
            float(values[i, j]))


_VEC3 = {'type': 'object', 'properties': {k: {'type': 'number'} for k in 'xyz'}}
#: JSON Schema of ``foxglove.Grid`` (Foxglove's schema; bytes as base64 in JSON).
GRID_SCHEMA = {
    'title': 'foxglove.Grid', 'type': 'object',
    'properties': {
        'timestamp': {'type': 'object', 'properties': {'sec': {'type': 'integer'},
                                                       'nsec': {'type': 'integer'}}},
        'frame_id': {'type': 'string'},
        'pose': {'type': 'object', 'properties': {
            'position': _VEC3,
            'orientation': {'type': 'object',
                            'properties': {k: {'type': 'number'} for k in 'xyzw'}}}},
        'column_count': {'type': 'integer'},
        'cell_size': {'type': 'object', 'properties': {k: {'type': 'number'} for k in 'xy'}},
        'row_stride': {'type': 'integer'},
        'cell_stride': {'type': 'integer'},
        'fields': {'type': 'array', 'items': {'type': 'object', 'properties': {
            'name': {'type': 'string'}, 'offset': {'type': 'integer'},
            'type': {'type': 'integer'}}}},
        'data': {'type': 'string', 'contentEncoding': 'base64'},
    },
}
