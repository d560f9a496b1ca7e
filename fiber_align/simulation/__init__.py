# SPDX-License-Identifier: Apache-2.0
"""
Offline simulation: the closed loop period by period, scenarios, scoring and tuning.

Above ``alignment`` and below ``analysis`` in the layering of docs/CONTRACTS.md.
"""
