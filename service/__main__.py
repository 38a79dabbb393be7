"""``python -m service``: the same as ``dacrt-service`` (``service.cli``)."""

from .cli import main

if __name__ == "__main__":
    main()
