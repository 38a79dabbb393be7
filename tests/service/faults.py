"""Faults of the data folder injected in process: writes that fail as a full disk, a read-only
mount or a failing device makes them fail."""

from __future__ import annotations

import os
from pathlib import Path

from service import persistence


def fail_in_write(monkeypatch, code: int, only: str = "") -> None:
    """Every file the data folder writes (or only those whose name starts with ``only``) stops
    half-way with OSError ``code``, as a full disk stops a write: the temporary file exists when
    it fails."""
    original = persistence.write_file

    def write_file(path: Path, write) -> None:
        if not path.name.startswith(only):
            return original(path, write)

        def half(file) -> None:
            file.write(b"half")
            raise OSError(code, os.strerror(code))

        original(path, half)

    monkeypatch.setattr(persistence, "write_file", write_file)


def temporary_files(folder: Path) -> list[str]:
    """The ``*.tmp`` files under ``folder``, relative to it."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*" + persistence.TEMPORARY))
