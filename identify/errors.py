"""Exceptions raised by the estimators."""

__all__ = ["NotIdentifiableError", "CorruptedSamplesError"]


class NotIdentifiableError(ValueError):
    """The data cannot determine the parameters (says why, and what to do instead)."""


class CorruptedSamplesError(ValueError):
    """Rows of a recording no motor can produce, or isolated residual outliers after a fit.

    Attributes
    ----------
    recording : int
        Index of the recording among those fitted.
    seq : tuple of int
        The rows' ``seq`` numbers.
    reason : str
        Why they are suspect.
    name : str, optional
        How the message names the recording (its file; default ``recordings[recording]``).
    """

    def __init__(self, recording: int, seq: tuple[int, ...], reason: str, name: str | None = None):
        self.recording, self.seq, self.reason = recording, tuple(seq), reason
        shown = ", ".join(map(str, self.seq[:10])) + (", ..." if len(self.seq) > 10 else "")
        name = name or f"recordings[{recording}]"
        super().__init__(f"{name}: {reason} at seq {shown}; a corrupted sample? fix the data, or "
                         "fit with outliers='drop' to drop them as gaps (--drop-outliers)")
