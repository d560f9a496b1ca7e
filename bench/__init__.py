# SPDX-License-Identifier: Apache-2.0
"""Benchmarks: speed and memory goals, run by ``make bench`` (never timed tests)."""
