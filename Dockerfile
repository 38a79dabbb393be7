# The ray-casting service with its demo scene: docker build -t dacrt . && docker run -p 8000:8000 dacrt
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    NUMBA_CACHE_DIR=/home/app/.cache/numba \
    DACRT_LOAD_DEMO=true

RUN useradd --create-home --uid 10001 app
WORKDIR /app
COPY pyproject.toml README.md ./
COPY dacrt ./dacrt
COPY service ./service
COPY scenes ./scenes
RUN pip install . && rm -rf build *.egg-info

USER app
# Compile the engine's kernels into Numba's cache now, so that the container is ready in seconds.
RUN python -c "import dacrt; print('warm-up', round(dacrt.warmup(), 1), 's')"

EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=5s --start-period=180s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(urllib.request.urlopen('http://127.0.0.1:8000/health', timeout=4).status != 200)"]
CMD ["uvicorn", "service.app:create_app", "--factory", "--http", "service.protocol:GuardedHttpProtocol", \
     "--host", "0.0.0.0", "--port", "8000"]
