"""The service's log lines, set up the same under ``python -m service`` and under
``uvicorn service.app:create_app --factory`` (whose logging config covers only uvicorn's
loggers)."""

from __future__ import annotations

import logging

FORMAT = "%(levelname)s:     %(name)s: %(message)s"  #: aligned with uvicorn's own lines


def configure_logging(level: str) -> None:
    """Send the ``service`` logger's records at ``level`` and above to stderr (once)."""
    logger = logging.getLogger("service")
    logger.setLevel(level.upper())
    if not any(getattr(h, "dacrt", False) for h in logger.handlers):
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter(FORMAT))
        handler.dacrt = True
        logger.addHandler(handler)
