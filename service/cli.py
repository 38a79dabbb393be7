"""``dacrt-service`` and ``python -m service``: serve the app under uvicorn with the guarded
HTTP protocol; every option mirrors a DACRT_* setting and wins over it."""

from __future__ import annotations

import argparse
import os
import socket
from collections.abc import Sequence

from pydantic import ByteSize

from . import __version__
from .settings import LOG_LEVELS, GiB, KiB, MiB, Settings, load_settings_or_exit, variable

UNITS = {"GiB": GiB, "MiB": MiB, "KiB": KiB, "": 1}

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
        "unless DACRT_LOAD_DEMO=false. Stop it with Ctrl-C. The first start compiles the "
        "engine's kernels (minutes; the log counts them); later starts load them from "
        "DACRT_CACHE_DIR in seconds. The API's pages are at /docs, a viewer at /.",
        epilog=settings_help(),
    )
    for option, (_, text) in OPTIONS.items():
        parser.add_argument(option, metavar=option.removeprefix("--").upper(), help=text)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return parser


def settings_help() -> str:
    """Every DACRT_* variable with its default, from ``Settings`` itself."""
    shown = []
    for field, info in Settings.model_fields.items():
        default = "unset" if info.default is None else info.default
        if info.annotation is ByteSize:
            unit = next(u for u in ("GiB", "MiB", "KiB", "") if default % UNITS[u] == 0)
            default = f"{default // UNITS[unit]}{unit}"
        if field == "load_demo":  # main turns it on unless the variable is set
            default = "true"
        shown.append(f"{variable(field)}={default}")
    return (
        "Settings come from the environment; an option above wins over its variable, and a "
        "DACRT_* name that is no setting stops the start. The variables and their defaults: "
        + ", ".join(shown)
        + " (DACRT_CACHE_DIR unset: ~/.cache/dacrt). Byte sizes take units (64MiB, 4GiB)."
    )


def check_port(settings: Settings) -> None:
    """End the process with one line when the settings' host and port cannot be listened on
    (another process listens there): uvicorn binds only after the app's startup has restored the
    data folder."""
    host, port = settings.host, settings.port
    if port == 0:  # any free port
        return
    try:
        # each address as asyncio's create_server binds it under uvicorn
        for family, kind, proto, _, address in socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        ):
            with socket.socket(family, kind, proto) as probe:
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if family == socket.AF_INET6:
                    probe.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                probe.bind(address)
    except OSError as exc:
        where = f"{settings.given('host')}, {settings.given('port')}"
        raise SystemExit(f"dacrt-service: {where}: cannot listen there: {exc}") from None


#: Seconds a stopping server waits for the requests in flight (a slow upload would hold it up to
#: DACRT_BODY_TIMEOUT), within the 10 s a container's stop allows before SIGKILL.
SHUTDOWN_GRACE_SECONDS = 5


def main(argv: Sequence[str] | None = None) -> None:
    import uvicorn

    from .app import create_app
    from .protocol import guarded_protocol

    arguments = vars(parser().parse_args(argv))
    given = {
        "--" + name.replace("_", "-"): value
        for name, value in arguments.items()
        if value is not None
    }
    overrides: dict[str, object] = {OPTIONS[option][0]: value for option, value in given.items()}
    # a message names the option given rather than the variable
    options = {OPTIONS[option][0]: option for option in given}
    if "DACRT_LOAD_DEMO" not in os.environ:
        overrides["load_demo"] = True
    settings = load_settings_or_exit(options, **overrides)
    check_port(settings)
    uvicorn.run(
        create_app(settings),
        host=settings.host,
        port=settings.port,
        http=guarded_protocol(settings),
        log_level=settings.log_level,
        timeout_graceful_shutdown=SHUTDOWN_GRACE_SECONDS,
    )
