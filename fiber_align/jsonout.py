# SPDX-License-Identifier: Apache-2.0
"""
JSON output of results: the one cleaner every ``--json`` and summary file goes through.

Results hold numpy scalars and arrays and non-finite floats (an unsettled step has an
infinite settling time, s). :func:`json_clean` makes them plain JSON: numpy scalars
become Python numbers, and non-finite floats become ``null`` or, where a reader needs
to tell ``inf`` from ``nan``, the strings ``"inf"``, ``"-inf"``, ``"nan"``.
"""

import math

import numpy as np


def json_clean(x, nonfinite_as_text=False, drop=()):
    """
    Return ``x`` made JSON-serialisable (see the module docstring).

    :param nonfinite_as_text: write non-finite floats as strings instead of ``null``.
    :param drop: mapping keys left out at every level (e.g. bulky traces).
    """
    if isinstance(x, dict):
        return {k: json_clean(v, nonfinite_as_text, drop) for k, v in x.items()
                if k not in drop}
    if isinstance(x, (list, tuple)):
        return [json_clean(v, nonfinite_as_text, drop) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return str(x) if nonfinite_as_text else None
    return x


def json_default(o):
    """Return a JSON stand-in for what ``json.dumps`` cannot write (its ``default=``)."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


# What json_clean(nonfinite_as_text=True) writes for the non-finite floats.
NONFINITE_TEXT = {'inf': math.inf, '-inf': -math.inf, 'nan': math.nan}


def json_restore(x):
    """Return ``x`` (parsed JSON) with the texts of :data:`NONFINITE_TEXT` as floats again."""
    if isinstance(x, dict):
        return {k: json_restore(v) for k, v in x.items()}
    if isinstance(x, list):
        return [json_restore(v) for v in x]
    if isinstance(x, str) and x in NONFINITE_TEXT:
        return NONFINITE_TEXT[x]
    return x
