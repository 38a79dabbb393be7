"""``dacrt-service`` and ``python -m service``: serve the app under uvicorn with the guarded
HTTP protocol; every option mirrors a DACRT_* setting and wins over it."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence

from . import __version__
from .settings import LOG_LEVELS, load_settings_or_exit

#: option -> (setting, help); the default shown is the setting's
OPTIONS = {
    "--host": ("host", "bind address (DACRT_HOST, default 127.0.0.1)"),
    "--port": ("port", "port (DACRT_PORT, default 8000)"),
    "--data-dir": (
        "data_dir",
        "folder that keeps the scenes across restarts (DACRT_DATA_DIR, default: memory only)",
    ),
    "--token-file": (
        "token_file",
        "file holding the bearer token every /v1 request must present (DACRT_TOKEN_FILE)",
    ),
    "--threads": ("threads", "engine threads per query (DACRT_THREADS, default: every core)"),
    "--log-level": ("log_level", f"{', '.join(LOG_LEVELS)} (DACRT_LOG_LEVEL, default info)"),
}


def parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dacrt-service",
        description="The dacrt ray-casting HTTP service, with the demo scene (scene 'demo') "
        "unless DACRT_LOAD_DEMO=false. Every DACRT_* setting is listed in the README.",
    )
    for option, (_, text) in OPTIONS.items():
        parser.add_argument(option, metavar=option.removeprefix("--").upper(), help=text)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    import uvicorn

    from .app import create_app
    from .protocol import guarded_protocol

    arguments = vars(parser().parse_args(argv))
    overrides: dict[str, object] = {
        OPTIONS["--" + name.replace("_", "-")][0]: value
        for name, value in arguments.items()
        if value is not None
    }
    if "DACRT_LOAD_DEMO" not in os.environ:
        overrides["load_demo"] = True
    settings = load_settings_or_exit(**overrides)
    uvicorn.run(
        create_app(settings),
        host=settings.host,
        port=settings.port,
        http=guarded_protocol(settings),
        log_level=settings.log_level,
    )
