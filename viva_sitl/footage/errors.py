"""The one error type of the footage package."""

from __future__ import annotations


class FootageError(ValueError):
    """Footage that cannot be used (missing, unreadable, bad metadata, failed download); the message says why."""
