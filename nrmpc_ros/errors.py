"""Errors users see: every one names the file, topic or field that is wrong."""


class NrmpcError(Exception):
    """Base class of the errors nrmpc_ros raises on purpose."""


class InputError(NrmpcError, ValueError):
    """Bad input: a file, a field, a topic or a message that cannot be used.

    The message always starts with where the problem is (``source``) and, when
    known, which field.
    """

    def __init__(self, source: str, message: str, field: str | None = None):
        self.source = str(source)
        self.field = field
        self.message = message
        where = f"{self.source}: field '{field}'" if field else self.source
        super().__init__(f"{where}: {message}")


class OptionError(InputError):
    """A library option out of range: a field of an options object or a keyword argument.

    It names the option as the library knows it (``owner`` and ``field``, e.g.
    ``bag options: field 'jpeg_quality'``); a command line that set the option
    from a flag reports the flag instead (``nrmpc_ros.cli.common.flag_error``).
    """

    def __init__(self, owner: str, field: str, message: str):
        super().__init__(owner, message, field)


class EstimationError(NrmpcError, RuntimeError):
    """An estimator cannot run on the given data (e.g. 4pt-bending without gravity)."""


ROS_EXTRA_HINT = "install the ros extra: pip install -e .[ros]"
