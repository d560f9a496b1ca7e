# SPDX-License-Identifier: Apache-2.0
"""
The run catalogue (docs/records.md): every run and alignment on record, pure (no rclpy).

``schema`` (the tables, their version, the migrations), ``backends`` (SQLite and
PostgreSQL by URL), ``writer`` (the writer that never makes its caller wait), ``rows``
(a run's and its alignments' rows), ``query`` (the reading tools' selections) and
``report`` (yield, Cpk/Ppk, control charts).
"""
