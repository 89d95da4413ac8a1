"""Former home of the figures, now :mod:`granbayes.figures` (kept for ``cli.py`` until it moves)."""

from .figures import plot_trajectory

__all__ = ["plot_trajectory"]
