"""The codec's exceptions: every error caused by bad input derives from ATMError."""

from __future__ import annotations


class ATMError(Exception):
    """Base class of every error the codec raises on bad input, options or files."""


class FormatError(ATMError):
    """The bytes are not a well-formed .atm file (bad signature, chunk or field)."""


class TruncatedError(FormatError):
    """The data ends before the file does."""


class CorruptError(FormatError):
    """A checksum or a structural invariant of the file does not hold."""


class UnsupportedError(ATMError):
    """The file or image uses something this version of the codec does not support."""


class LimitError(ATMError):
    """The image or file exceeds a configured safety limit (see codec.limits)."""


class OptionError(ATMError, ValueError):
    """An encoder or decoder option is unknown or out of range."""


class BackendError(ATMError):
    """A decoding backend (e.g. OpenGL) cannot be used on this machine."""
