"""Exceptions raised by the estimators."""

__all__ = ["NotIdentifiableError"]


class NotIdentifiableError(ValueError):
    """The data cannot determine the parameters (says why, and what to do instead)."""
