"""``python -m service``: serve on 127.0.0.1:8000 (DACRT_HOST, DACRT_PORT) with the demo scene."""

from __future__ import annotations

import logging
import os

import uvicorn

from .app import create_app
from .protocol import guarded_protocol
from .settings import load_settings_or_exit


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s:     %(name)s: %(message)s")
    overrides = {} if "DACRT_LOAD_DEMO" in os.environ else {"load_demo": True}
    settings = load_settings_or_exit(**overrides)
    uvicorn.run(
        create_app(settings),
        host=settings.host,
        port=settings.port,
        http=guarded_protocol(settings),
    )


if __name__ == "__main__":
    main()
