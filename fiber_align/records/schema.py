# SPDX-License-Identifier: Apache-2.0
"""
The run catalogue's schema: its two tables, its version, the migrations between versions.

THE column lists (:data:`RUN_COLUMNS`, :data:`ALIGNMENT_COLUMNS`) are read by the
backends, the writer, the reading tools and the report; each column has a kind that maps
to one SQL type per dialect (:data:`TYPES`). Times are text, ISO 8601 UTC with a fixed
width (``2026-12-05T07:30:04.123456Z``), so they sort and compare alike on SQLite and
PostgreSQL; JSON columns are text.

Version 1 is the layout of issue 41 (``runs``, ``alignments``); version 2 adds the
run's ``snapshot_paths`` (the flight recorder's bags, a JSON list) and the indexes of
the reading tools' filters. A catalogue is created at version 1 and migrated step by step,
so a new one and an old one go through the same statements. The version lives in the
table ``catalog_schema`` (one row); a catalogue of a newer version is refused.
"""

#: The version this package writes and reads.
SCHEMA_VERSION = 2
#: The table holding the version (one row: ``version``, ``package_version``).
VERSION_TABLE = 'catalog_schema'

#: Column kind -> SQL type, per dialect.
TYPES = {
    'sqlite': {'text': 'TEXT', 'time': 'TEXT', 'json': 'TEXT', 'int': 'INTEGER',
               'real': 'REAL', 'bool': 'INTEGER'},
    'postgresql': {'text': 'TEXT', 'time': 'TEXT', 'json': 'TEXT', 'int': 'BIGINT',
                   'real': 'DOUBLE PRECISION', 'bool': 'BOOLEAN'},
}
DIALECTS = tuple(TYPES)

#: ``runs`` at version 1: (name, kind); ``run_id`` (a UUID) is the key.
RUN_COLUMNS_V1 = (
    ('run_id', 'text'), ('started_at', 'time'), ('ended_at', 'time'), ('machine', 'text'),
    ('sync_mode', 'text'), ('hardware', 'bool'), ('package_version', 'text'),
    ('parameters', 'json'), ('bag_path', 'text'), ('cycles_kept', 'int'),
    ('watchdog_trips', 'int'), ('end_reason', 'text'))
#: ``runs`` now.
RUN_COLUMNS = RUN_COLUMNS_V1 + (('snapshot_paths', 'json'),)
#: ``alignments``: (name, kind); ``(run_id, seq)`` is the key, ``seq`` 1, 2, ... per run.
ALIGNMENT_COLUMNS = (
    ('run_id', 'text'), ('seq', 'int'), ('part_id', 'text'), ('started_at', 'time'),
    ('ended_at', 'time'), ('final_state', 'text'), ('fault_reason', 'text'),
    ('time_to_first_light_s', 'real'), ('time_to_peak_s', 'real'), ('peak_power_w', 'real'),
    ('final_loss_db', 'real'), ('samples', 'int'), ('figures', 'json'))
#: table -> (columns, key columns)
TABLES = {'runs': (RUN_COLUMNS, ('run_id',)),
          'alignments': (ALIGNMENT_COLUMNS, ('run_id', 'seq'))}


class CatalogError(Exception):
    """The catalogue cannot be used; the message is one line for the operator."""


def names(table):
    """Return the column names of ``table`` (``runs`` or ``alignments``), in order."""
    return tuple(c for c, _ in TABLES[table][0])


def kinds(table):
    """Return ``{column: kind}`` of ``table``."""
    return dict(TABLES[table][0])


def _create(table, columns, key, dialect):
    cols = ', '.join('%s %s' % (c, TYPES[dialect][k]) for c, k in columns)
    return 'CREATE TABLE IF NOT EXISTS %s (%s, PRIMARY KEY (%s))' % (table, cols, ', '.join(key))


def create_v1(dialect):
    """Return the statements that create an empty catalogue of version 1."""
    return [
        'CREATE TABLE IF NOT EXISTS %s (version INTEGER NOT NULL, package_version TEXT)'
        % VERSION_TABLE,
        _create('runs', RUN_COLUMNS_V1, ('run_id',), dialect),
        _create('alignments', ALIGNMENT_COLUMNS, ('run_id', 'seq'), dialect),
        'INSERT INTO %s (version, package_version) VALUES (1, NULL)' % VERSION_TABLE,
    ]


def migrations(dialect):
    """Return ``{from version: statements}`` that take a catalogue one version up."""
    return {
        1: ['ALTER TABLE runs ADD COLUMN snapshot_paths %s' % TYPES[dialect]['json'],
            'CREATE INDEX IF NOT EXISTS alignments_part ON alignments (part_id)',
            # the order of every selection (start, run, seq): no sort of its own
            'CREATE INDEX IF NOT EXISTS alignments_started ON alignments (started_at, '
            'run_id, seq)',
            'CREATE INDEX IF NOT EXISTS runs_machine ON runs (machine)'],
    }


def check_version(found, where):
    """
    Raise :class:`CatalogError` (one line) for a catalogue this package cannot read.

    :param found: the catalogue's version (int); :param where: the catalogue, for the line.
    """
    if found > SCHEMA_VERSION:
        raise CatalogError(
            'catalogue %s has schema version %d, newer than the %d this fiber_align reads: '
            'upgrade fiber_align or give another catalogue' % (where, found, SCHEMA_VERSION))
    if found < 1:
        raise CatalogError('catalogue %s has no valid schema version (%r)' % (where, found))


def upsert(table, dialect):
    """
    Return the idempotent insert of one row of ``table`` (placeholders of ``dialect``).

    An alignment (key ``run_id, seq``) is written once: a second copy (a spool replayed
    after a commit whose acknowledgement was lost) changes nothing. A run is written at
    its start and again at its end: a column the new row leaves NULL keeps its value.
    """
    columns, key = TABLES[table]
    cols = [c for c, _ in columns]
    mark = '?' if dialect == 'sqlite' else '%s'
    sql = 'INSERT INTO %s (%s) VALUES (%s) ON CONFLICT (%s) DO ' % (
        table, ', '.join(cols), ', '.join([mark] * len(cols)), ', '.join(key))
    if table == 'alignments':
        return sql + 'NOTHING'
    rest = [c for c in cols if c not in key]
    return sql + 'UPDATE SET ' + ', '.join(
        '%s = COALESCE(excluded.%s, %s.%s)' % (c, c, table, c) for c in rest)
