# SPDX-License-Identifier: Apache-2.0
"""Emulated MDT693B amplifier (pty) and PM100 power meter (TCP) carrying this package's physics."""
