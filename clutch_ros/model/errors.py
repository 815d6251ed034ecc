"""Exceptions of the model core, all rooted in :class:`clutch_ros.errors.ClutchError`.

Hierarchy::

    ClutchError
    ├── ModelError
    │   ├── ParameterError (also a ConfigError)   bad/missing parameter; names the key
    │   ├── InputError                            bad input sample or array
    │   │   └── SampleRejected                    a live sample refused, state untouched
    │   │       ├── NonFiniteSample               NaN or inf in a stamp or an input
    │   │       ├── OutOfOrderSample              stamp older than the last accepted one
    │   │       └── DuplicateSample               stamp equal to the last accepted one
    │   ├── UnreachableTorqueError                inverse asked for more than the clutch gives
    │   ├── CalibrationError                      FlexiForce data cannot fix the calibration
    │   ├── KernelUnavailableError                engine="kernel" but the compiled loop cannot run
    │   ├── UnknownLawError (also a ParameterError) a spline law that is not registered
    │   └── IdentificationError                   the data cannot identify the model
    │       ├── NoMeasuredTorqueError             no run carries a measured torque
    │       ├── TooShortError                     too little data with a measured torque
    │       ├── NoExcitationError                 the actuating pressure hardly varies
    │       └── UnidentifiableParameterError      a parameter has no effect or is confounded
    └── ConfigError
"""

from __future__ import annotations

from collections.abc import Sequence

from clutch_ros.errors import ClutchError, ConfigError

__all__ = [
    "ModelError",
    "ParameterError",
    "InputError",
    "SampleRejected",
    "NonFiniteSample",
    "OutOfOrderSample",
    "DuplicateSample",
    "UnreachableTorqueError",
    "CalibrationError",
    "KernelUnavailableError",
    "UnknownLawError",
    "IdentificationError",
    "NoMeasuredTorqueError",
    "TooShortError",
    "NoExcitationError",
    "UnidentifiableParameterError",
]


class ModelError(ClutchError):
    """Base class of every error raised by ``clutch_ros.model``."""


class ParameterError(ModelError, ConfigError):
    """A model parameter is missing, unknown, non-finite, of the wrong type or out of range.

    The message always names the offending dotted key (``friction.mu_ref``); ``source``
    (a file name) is prefixed when known. Attributes: ``key``, ``reason``, ``source``.
    """

    def __init__(self, key: str, reason: str, source: str | None = None):
        self.key = key
        self.reason = reason
        self.source = source
        prefix = f"{source}: " if source else ""
        super().__init__(f"{prefix}parameter '{key}': {reason}")

    def with_source(self, source: str) -> ParameterError:
        """Return a copy of this error whose message is prefixed with ``source``."""
        return ParameterError(self.key, self.reason, source)


class InputError(ModelError):
    """An input value or array given to the model is invalid (shape, NaN, order...)."""


class SampleRejected(InputError):  # noqa: N818 - name fixed by the API contract
    """A live sample was refused; the estimator's state is exactly as before the call."""


class NonFiniteSample(SampleRejected):
    """A stamp or an input of the sample is NaN or infinite."""


class OutOfOrderSample(SampleRejected):
    """The sample's stamp is older than the last accepted stamp."""


class DuplicateSample(SampleRejected):
    """The sample's stamp equals the last accepted stamp."""


class UnreachableTorqueError(ModelError):
    """The requested torque exceeds what the clutch transmits at its maximum pressure."""


class CalibrationError(ModelError):
    """The FlexiForce data cannot determine the calibration (names the sensor or cause)."""


class KernelUnavailableError(ModelError):
    """``engine="kernel"`` was asked for but the compiled kernel cannot run (says why)."""


class UnknownLawError(ParameterError):
    """``spline.law`` names no registered spline-friction law (:mod:`~.laws`)."""

    def __init__(self, name: str, known: Sequence[str], source: str | None = None):
        self.name = name
        self.known = tuple(known)
        super().__init__("spline.law", f"unknown spline law {name!r} (one of "
                         f"{', '.join(self.known)})", source)

    def with_source(self, source: str) -> UnknownLawError:
        """Return a copy of this error whose message is prefixed with ``source``."""
        return UnknownLawError(self.name, self.known, source)


class IdentificationError(ModelError):
    """The data cannot identify the model (the message says why and what to change).

    ``keys``: the dotted parameter keys concerned (may be empty).
    """

    def __init__(self, message: str, keys: Sequence[str] = ()):
        super().__init__(message)
        self.keys = tuple(keys)


class NoMeasuredTorqueError(IdentificationError):
    """No run carries a measured torque to fit against."""


class TooShortError(IdentificationError):
    """Too little data with a measured torque (duration or samples per parameter)."""


class NoExcitationError(IdentificationError):
    """The actuating pressure (the model's input) hardly varies."""


class UnidentifiableParameterError(IdentificationError):
    """A parameter (``keys``) has no effect or is confounded with others on these data."""
