"""Errors that the CLI reports as one clear line instead of a traceback."""


class UserError(Exception):
    """Bad file, bad argument or missing device: the user can fix it.

    The CLI prints ``tpods: error: <message>`` and exits with status 2.
    """


class DeviceError(UserError):
    """A device did not answer, answered nonsense or refused a command."""
