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
    │   └── UnreachableTorqueError                inverse asked for more than the clutch gives
    └── ConfigError
"""

from __future__ import annotations

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
