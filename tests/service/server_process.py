"""A real server in a subprocess, started the way users start it, for the service tests."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time

import httpx
import pytest
from service_helpers import REPO

STARTUP_SECONDS = 180


class ServerProcess:
    """``python -m service`` (what users run; or ``python -m COMMAND...``, where ``{port}`` stands
    for the port) on a free loopback port, without the demo scene unless ``env`` asks for it."""

    def __init__(self, env: dict[str, str], command: list[str] | None = None) -> None:
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            self.port = probe.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = tempfile.TemporaryFile()
        # settings come only from ``env``, whatever DACRT_* the test run itself has
        inherited = {k: v for k, v in os.environ.items() if not k.upper().startswith("DACRT_")}
        pythonpath = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
        where = {
            "DACRT_HOST": "127.0.0.1",
            "DACRT_PORT": str(self.port),
            "DACRT_LOAD_DEMO": "false",
        }
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                *(part.format(port=self.port) for part in command or ["service"]),
            ],
            cwd=REPO,
            env={**inherited, "PYTHONPATH": pythonpath, **where, **env},
            stdout=self.log,
            stderr=subprocess.STDOUT,
        )

    def output(self, last: int = 4000) -> str:
        """The last ``last`` characters the server printed."""
        self.log.seek(0)
        return self.log.read().decode(errors="replace")[-last:]

    def wait_ready(self) -> str:
        """Wait until /health says ok; fail with the server's output if it dies or times out."""
        deadline = time.monotonic() + STARTUP_SECONDS
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                pytest.fail(f"server exited with {self.process.returncode}:\n{self.output()}")
            try:
                if httpx.get(f"{self.url}/health", timeout=2).json().get("status") == "ok":
                    return self.url
            except (httpx.HTTPError, ValueError):
                pass
            time.sleep(0.25)
        pytest.fail(f"server not ready after {STARTUP_SECONDS} s:\n{self.output()}")

    def kill(self) -> None:
        """SIGKILL: the server gets no chance to finish anything."""
        self.process.kill()
        self.process.wait()

    def stop(self) -> None:
        self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        self.log.close()
