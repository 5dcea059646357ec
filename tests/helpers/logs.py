"""What an app logged, as the error tests read it."""

from __future__ import annotations

import logging


def error_text(caplog) -> str:
    """The messages logged at ERROR or above, joined by spaces (``caplog`` is pytest's fixture)."""
    return " ".join(r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR)
