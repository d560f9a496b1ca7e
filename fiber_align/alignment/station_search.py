# SPDX-License-Identifier: Apache-2.0
"""
Geometry of the coupled station's search (four axes; pure numpy, SI units).

- :func:`search_design`: how many input-side grid points and output-side raster lines the
  first-light search needs so that it cannot pass the joint peak by.
- :func:`search_vertices` and :class:`Polyline`: the search path in the four coordinates
  ``(x_in, y_in, x_out, y_out)`` (m), walked at a constant speed.
"""

import math

import numpy as np

from fiber_align.alignment import search2d as s2

SQRT2 = math.sqrt(2.0)


def search_design(radius_m, capture_db, slow_share, chord_m, half_width_m):
    """
    Return ``(n_grid, n_lines)``: input grid points per axis, output raster lines.

    Light reaches the detector when ``(d_in^2 + d_out^2) / radius^2 <= D ln(10) / 10``,
    ``D = capture_db``. The input side holds still at the points of an ``n_grid`` square
    grid over ``+-half_width_m``, at most ``pitch / sqrt(2)`` from its peak; that share
    (``slow_share`` of ``D``) is :func:`~fiber_align.alignment.search2d.capture_radius`.
    The output side rasters its square with lines no further apart than
    :func:`~fiber_align.alignment.search2d.spiral_pitch` allows for the rest of ``D`` and
    the confirm chord ``chord_m`` (m).
    """
    if not 0.0 < slow_share < 1.0:
        raise ValueError('search_slow_share must be in (0, 1), got %r' % slow_share)
    d_slow = s2.capture_radius(radius_m, slow_share * capture_db)
    n = max(1, int(math.ceil(2.0 * half_width_m / (SQRT2 * d_slow))))
    pitch = s2.spiral_pitch(radius_m, (1.0 - slow_share) * capture_db, chord_m)
    m = max(1, int(math.ceil(2.0 * half_width_m / pitch)))
    return n, m


def grid_points(center, half_width_m, n):
    """Return the ``n`` by ``n`` cell centres of a square (m), rows in serpentine order."""
    c = (np.arange(n) + 0.5) * (2.0 * half_width_m / n) - half_width_m
    out = []
    for j in range(n):
        xs = c if j % 2 == 0 else c[::-1]
        out += [(center[0] + x, center[1] + c[j]) for x in xs]
    return np.asarray(out)


def raster_vertices(center, half_width_m, m):
    """Return the corners (m) of an ``m``-line serpentine raster of a square, lines along x."""
    ys = (np.arange(m) + 0.5) * (2.0 * half_width_m / m) - half_width_m
    out = []
    for j, y in enumerate(ys):
        xs = (-half_width_m, half_width_m) if j % 2 == 0 else (half_width_m, -half_width_m)
        out += [(center[0] + xs[0], center[1] + y), (center[0] + xs[1], center[1] + y)]
    return np.asarray(out)


def search_vertices(start, center_in, center_out, half_width_m, n, m, lo, hi):
    """
    Return the search path's vertices ``(k, 4)`` (m), clipped to ``lo..hi`` (m).

    From ``start`` to the first grid point and the raster's first corner; then at each
    input grid point one raster pass of the output side, the next pass backwards, the
    input side stepping to its next point while the output side waits at the pass's end.
    """
    grid = grid_points(center_in, half_width_m, n)
    ras = raster_vertices(center_out, half_width_m, m)
    rows = [np.asarray(start, dtype=float)]
    for i, g in enumerate(grid):
        path = ras if i % 2 == 0 else ras[::-1]
        for q in path:
            rows.append(np.array([g[0], g[1], q[0], q[1]]))
    return np.clip(np.asarray(rows), lo, hi)


class Polyline:
    """A path through ``vertices`` ``(k, d)`` (m), walked by arc length."""

    def __init__(self, vertices):
        """Start at the first vertex."""
        self.v = np.asarray(vertices, dtype=float)
        seg = np.linalg.norm(np.diff(self.v, axis=0), axis=1)
        self.cum = np.concatenate([[0.0], np.cumsum(seg)])
        self.length_m = float(self.cum[-1])
        self.s = 0.0
        self.done = self.length_m <= 0.0

    def advance(self, ds_m):
        """Walk ``ds_m`` (m) further; return the point (m)."""
        self.s = min(self.s + float(ds_m), self.length_m)
        self.done = self.s >= self.length_m
        i = int(np.searchsorted(self.cum, self.s, side='right')) - 1
        i = min(max(i, 0), len(self.v) - 2) if len(self.v) > 1 else 0
        if len(self.v) == 1:
            return self.v[0].copy()
        span = self.cum[i + 1] - self.cum[i]
        f = 0.0 if span <= 0 else (self.s - self.cum[i]) / span
        return self.v[i] + f * (self.v[i + 1] - self.v[i])
