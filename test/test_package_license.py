# SPDX-License-Identifier: Apache-2.0
"""Every source file carries an SPDX license line (ament_copyright is not available here)."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SKIP = {'.venv', '.git', 'build', 'install', 'log', 'runs', 'out'}


def source_files():
    """Yield every Python source file of the project."""
    for p in ROOT.rglob('*.py'):
        if not SKIP.intersection(p.relative_to(ROOT).parts):
            yield p


def test_every_python_file_has_spdx_line():
    files = list(source_files())
    assert len(files) > 10
    missing = [str(p.relative_to(ROOT)) for p in files
               if 'SPDX-License-Identifier: Apache-2.0' not in p.read_text().splitlines()[0]]
    assert not missing, 'files without an SPDX line as their first line: %s' % missing


def test_package_xml_declares_the_same_license():
    text = (ROOT / 'package.xml').read_text()
    assert '<license>Apache-2.0</license>' in text
