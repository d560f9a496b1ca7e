# SPDX-License-Identifier: Apache-2.0
"""
One source of defaults: ROS params-file YAML under ``config/``.

A params file maps node names to ``{ros__parameters: {...}}``. The nodes load these
files through ``--ros-args --params-file``; the CLI, the tests and the benchmarks load
the same files through :func:`load_params`, so a default lives in exactly one place.
"""

import os
from pathlib import Path

import yaml


class ConfigError(ValueError):
    """A configuration file or value is wrong; the message names what and what is allowed."""


def config_dir():
    """
    Return the directory holding the shipped ``*.yaml`` files.

    Looked up in order: ``$FIBER_ALIGN_CONFIG_DIR``, the source tree (``../config``
    beside the package, the pip editable and test case), and the installed share
    directory ``<prefix>/share/fiber_align/config`` (the colcon case).
    """
    env = os.environ.get('FIBER_ALIGN_CONFIG_DIR')
    candidates = []
    if env:
        candidates.append(Path(env))
    here = Path(__file__).resolve().parent
    candidates.append(here.parent / 'config')
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory('fiber_align')) / 'config')
    except Exception:  # noqa: BLE001 - ament index is optional outside ROS
        pass
    import sys
    candidates.append(Path(sys.prefix) / 'share' / 'fiber_align' / 'config')
    for c in candidates:
        if c.is_dir() and any(c.glob('*.yaml')):
            return c
    raise ConfigError('cannot find the fiber_align config directory; set FIBER_ALIGN_CONFIG_DIR '
                      '(looked in: %s)' % ', '.join(str(c) for c in candidates))


def config_path(name):
    """Return the path of a config file: an existing path, or a name in :func:`config_dir`."""
    p = Path(name)
    if p.is_file():
        return p
    q = config_dir() / name
    if not q.is_file():
        raise ConfigError('config file %r not found (looked in %s)' % (name, config_dir()))
    return q


def read_yaml(path):
    """Read a YAML file; raise :class:`ConfigError` with the path on any failure."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError('config file %s does not exist' % p)
    try:
        with open(p, 'r', encoding='utf-8') as f:
            data = yaml.safe_load(f)
    except yaml.YAMLError as exc:
        raise ConfigError('config file %s is not valid YAML: %s' % (p, exc)) from None
    if not isinstance(data, dict):
        raise ConfigError('config file %s must hold a mapping, got %s'
                          % (p, type(data).__name__))
    return data


def load_params(path, node=None):
    """
    Return the ``ros__parameters`` mapping of ``node`` in a ROS params file.

    :param path: a path, or the name of a file in :func:`config_dir`.
    :param node: node name (with or without leading ``/``); ``None`` takes the only
        node in the file, or ``/**``.
    :raises ConfigError: the file, the node or its ``ros__parameters`` is missing.
    """
    p = config_path(path) if not Path(path).is_file() else Path(path)
    data = read_yaml(p)
    keys = list(data.keys())
    if node is None:
        if len(keys) == 1:
            key = keys[0]
        elif '/**' in data:
            key = '/**'
        else:
            raise ConfigError('%s holds several nodes (%s); name one' % (p, ', '.join(keys)))
    else:
        names = [node, '/' + node.lstrip('/'), node.lstrip('/')]
        key = next((k for k in names if k in data), None)
        if key is None:
            if '/**' in data:
                key = '/**'
            else:
                raise ConfigError('%s has no section for node %r (has: %s)'
                                  % (p, node, ', '.join(keys)))
    section = data[key]
    if not isinstance(section, dict) or 'ros__parameters' not in section:
        raise ConfigError('%s: section %r must hold ros__parameters' % (p, key))
    params = section['ros__parameters']
    if not isinstance(params, dict):
        raise ConfigError('%s: %r ros__parameters must be a mapping' % (p, key))
    return dict(params)


def flatten(params, prefix=''):
    """Flatten nested parameter mappings to ROS dotted names (``a: {b: 1}`` -> ``a.b``)."""
    out = {}
    for k, v in params.items():
        name = prefix + str(k)
        if isinstance(v, dict):
            out.update(flatten(v, name + '.'))
        else:
            out[name] = v
    return out


class _ParamsDumper(yaml.SafeDumper):
    """A SafeDumper that quotes the strings ROS's params parser would read as booleans."""


#: Strings rcl's YAML parser reads as booleans (YAML 1.1) that PyYAML leaves bare.
RCL_BOOLEAN_WORDS = frozenset(('y', 'Y', 'n', 'N'))


def _str(dumper, value):
    style = "'" if value in RCL_BOOLEAN_WORDS else None
    return dumper.represent_scalar('tag:yaml.org,2002:str', value, style=style)


_ParamsDumper.add_representer(str, _str)


def dump_params(data, stream):
    """Write ``data`` (a params mapping) as YAML that ROS reads back as written."""
    yaml.dump(data, stream, Dumper=_ParamsDumper, sort_keys=False)


def write_params(path, node, params, header=''):
    """
    Write ``params`` as a ROS params file with one ``node`` section.

    :param header: comment text put first, one ``#`` line per line (what wrote the file).
    """
    with open(path, 'w', encoding='utf-8') as f:
        for line in header.splitlines():
            f.write(('# ' + line).rstrip() + '\n')
        dump_params({node: {'ros__parameters': params}}, f)


def unflatten(flat):
    """Turn ROS dotted names back into the nested mapping of the params file."""
    out = {}
    for name, value in flat.items():
        parts = name.split('.')
        d = out
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = list(value) if isinstance(value, (list, tuple)) or (
            hasattr(value, 'tolist')) else value
    return out
