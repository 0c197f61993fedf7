"""The error of an identification request the data or the model cannot answer."""


class IdentifyError(ValueError):
    """An identification request cannot be carried out; the message says which parameter or
    which data and why."""
