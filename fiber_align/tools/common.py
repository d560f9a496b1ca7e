# SPDX-License-Identifier: Apache-2.0
"""What every ``fiber-align`` sub-command shares: the usage error."""


class UsageError(Exception):
    """Bad command-line usage; ``fiber-align`` exits 2 with the message."""
