# SPDX-License-Identifier: Apache-2.0
"""Every module of the package imports (a moved name fails here, not in a graph's child)."""

import importlib
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
MODULES = sorted('.'.join(p.relative_to(ROOT).with_suffix('').parts).replace('.__init__', '')
                 for p in (ROOT / 'fiber_align').rglob('*.py') if p.name != '__main__.py')


@pytest.mark.parametrize('name', MODULES)
def test_module_imports(name):
    importlib.import_module(name)
