"""Warnings shared across the subpackages."""


class SensitivityWarning(UserWarning):
    """A sensitivity may be unreliable: pathwise tangents that blow up, or a standard error large against the value."""


class StepSizeWarning(UserWarning):
    """The time step lies near RK4's stability bound for the fastest mode of the linearised model."""
