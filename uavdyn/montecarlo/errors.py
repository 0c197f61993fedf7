"""The error type of the Monte-Carlo package, in a module of its own so every module of the
package raises it without importing the study specification."""


class MonteCarloError(ValueError):
    """A Monte-Carlo study cannot be set up or run as asked; the message says why."""


__all__ = ["MonteCarloError"]
