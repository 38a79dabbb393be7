"""The service's log lines, set up the same under ``python -m service`` and under
``uvicorn service.app:create_app --factory`` (whose logging config covers only uvicorn's
loggers). What a request sends (its path, a header's value) goes into a line through
``untrusted``."""

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


#: Characters of a request's path or header value that a log line keeps.
MOST_LOGGED = 200


def untrusted(text: str, most: int = MOST_LOGGED) -> str:
    """``text`` from a request (its path, a header's value) for a log line: a backslash, a
    control character (newline, ESC) and any other than ASCII written as Python escapes them
    (``\\n``, ``\\x1b``), so that a client cannot start a line of its own or colour a terminal,
    and cut to its first ``most`` characters, with its length."""
    escaped = text.encode("unicode_escape").decode("ascii")
    if len(escaped) <= most:
        return escaped
    return f"{escaped[:most]}... ({len(text)} characters)"
