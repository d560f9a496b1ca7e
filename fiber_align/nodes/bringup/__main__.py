# SPDX-License-Identifier: Apache-2.0
"""``python -m fiber_align.nodes.bringup``: the same as the ``bringup`` executable."""

from fiber_align.nodes.bringup import main

main()
