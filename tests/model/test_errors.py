"""The model's exception hierarchy and the contract that ParameterError names its key."""

import pytest

from clutch_ros.errors import ClutchError, ConfigError, DataError
from clutch_ros.model import errors


def test_hierarchy():
    assert issubclass(errors.ModelError, ClutchError)
    assert issubclass(errors.ParameterError, errors.ModelError)
    assert issubclass(errors.ParameterError, ConfigError)
    assert issubclass(errors.InputError, errors.ModelError)
    assert not issubclass(errors.InputError, DataError)
    for cls in (errors.NonFiniteSample, errors.OutOfOrderSample, errors.DuplicateSample):
        assert issubclass(cls, errors.SampleRejected)
        assert issubclass(cls, errors.InputError)
    assert issubclass(errors.UnreachableTorqueError, errors.ModelError)


def test_parameter_error_names_key_and_source():
    err = errors.ParameterError("friction.mu_ref", "must be > 0")
    assert "friction.mu_ref" in str(err) and err.key == "friction.mu_ref"
    located = err.with_source("params/x.yaml")
    assert str(located).startswith("params/x.yaml: ") and "friction.mu_ref" in str(located)
    with pytest.raises(ConfigError, match="friction.mu_ref"):
        raise located


def test_every_model_exception_lives_in_errors_and_keeps_its_old_import():
    from clutch_ros.model import calibration, fit_data, identification, kernel

    for module, names in ((calibration, ("CalibrationError",)),
                          (kernel, ("KernelUnavailableError",)),
                          (fit_data, ("IdentificationError", "NoMeasuredTorqueError",
                                      "TooShortError", "NoExcitationError",
                                      "UnidentifiableParameterError")),
                          (identification, ("IdentificationError",))):
        for name in names:
            assert getattr(module, name) is getattr(errors, name), name
            assert issubclass(getattr(errors, name), errors.ModelError)
    for name in ("NoMeasuredTorqueError", "TooShortError", "NoExcitationError",
                 "UnidentifiableParameterError"):
        assert issubclass(getattr(errors, name), errors.IdentificationError)
    assert issubclass(errors.UnknownLawError, errors.ParameterError)
