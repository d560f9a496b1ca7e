# SPDX-License-Identifier: Apache-2.0
"""``python -m fiber_align.bringup``: the same as the ``bringup`` executable."""

from fiber_align.bringup import main

main()
