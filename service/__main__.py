"""``python -m service`` and ``dacrt-service``: the server (``service.cli``), or one line saying
how to install the web stack when it is missing."""

from __future__ import annotations

from collections.abc import Sequence

MISSING = (
    "dacrt-service: {name} is not installed; the service needs the 'service' extra: "
    "pip install 'dacrt-service[service]' (in a checkout: pip install '.[service]')"
)


def main(argv: Sequence[str] | None = None) -> None:
    try:
        import uvicorn  # noqa: F401

        from .app import create_app  # noqa: F401  every web package the server imports
        from .cli import main as serve
    except ModuleNotFoundError as exc:
        raise SystemExit(MISSING.format(name=exc.name)) from None
    serve(argv)


if __name__ == "__main__":
    main()
