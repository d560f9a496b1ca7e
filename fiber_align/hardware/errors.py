# SPDX-License-Identifier: Apache-2.0
"""Typed device errors: every failure of a device says which device and why."""

PORT_GONE = 'port gone'
WRITE_ERROR = 'write error'
NO_PROMPT = 'no prompt within timeout'
NO_REPLY = 'no reply within timeout'
CMD_NOT_DEFINED = 'CMD_NOT_DEFINED'
BAD_REPLY = 'bad reply'
NOT_CONNECTED = 'not connected'
LIMIT = 'limit'
WRONG_DEVICE = 'wrong device'
INSTRUMENT_ERROR = 'instrument error'


class DeviceError(RuntimeError):
    """
    A device failed; ``reason`` is one of the module constants, ``detail`` says more.

    ``str(err)`` is one line: ``<device>: <reason>: <detail>``, ready for
    ``/diagnostics`` or a log, never a traceback.
    """

    def __init__(self, device, reason, detail=''):
        """Store the device name, the reason (a module constant) and the detail text."""
        self.device = str(device)
        self.reason = str(reason)
        self.detail = str(detail)
        text = '%s: %s' % (self.device, self.reason)
        if self.detail:
            text += ': ' + self.detail
        super().__init__(text)


class LimitError(DeviceError, ValueError):
    """A value was refused before it reached the device (outside the allowed range)."""

    def __init__(self, device, detail):
        """Refuse with ``reason`` :data:`LIMIT`."""
        super().__init__(device, LIMIT, detail)
