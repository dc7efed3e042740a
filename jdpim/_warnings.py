"""Warnings shared across the subpackages."""


class SensitivityWarning(UserWarning):
    """A sensitivity may be unreliable: pathwise tangents that blow up, or a standard error large against the value."""
