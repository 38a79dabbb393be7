# The ray-casting service with its demo scene: docker build -t dacrt . && docker run -p 8000:8000 dacrt
# Scenes survive a restart with a volume: docker run -p 8000:8000 -v dacrt-data:/data dacrt
# (a host folder mounted on /data must be writable by uid 10001, the server's user)
FROM python:3.11-slim

# Numba's compiled kernels go to DACRT_CACHE_DIR. Numba keys them by the CPU it compiled for:
# the warm-up below compiles for the build machine's CPU, and a container started on a different
# CPU (another model or instruction set) compiles again at its first start (1 to 15 minutes, /health
# says "starting" meanwhile; in a child process of the server, about 3 GB at its peak) into the
# container's own copy of the folder. Build the image where it runs, or mount a volume on
# /home/app/.cache/dacrt to keep a compile across containers.
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    DACRT_CACHE_DIR=/home/app/.cache/dacrt \
    DACRT_DATA_DIR=/data \
    DACRT_LOAD_DEMO=true

RUN useradd --create-home --uid 10001 app && mkdir /data && chown app /data
WORKDIR /app
COPY pyproject.toml README.md ./
COPY dacrt ./dacrt
COPY service ./service
RUN pip install ".[service]" && rm -rf build *.egg-info

USER app
# Compile every kernel a request reaches into DACRT_CACHE_DIR now, so that the container is ready
# in seconds (on this CPU). The kernels are filed by a digest of the engine's sources, so the
# server finds them whichever copy of the sources it imports.
RUN python -m service.warmup
# Any uid may run it (docker run --user, OpenShift): such a uid is in group 0, which may write
# the kernels' cache and the data folder as their owner may (and enter the home that holds the cache,
# whatever mode useradd gave it).
USER root
RUN chgrp -R 0 /home/app/.cache /data && chmod -R g+rwX /home/app/.cache /data \
    && chgrp 0 /home/app && chmod g+rx /home/app
USER app

VOLUME /data
EXPOSE 8000
# The start period covers a compile on another CPU (up to 15 minutes on two busy cores).
HEALTHCHECK --interval=15s --timeout=5s --start-period=900s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(urllib.request.urlopen('http://127.0.0.1:8000/health', timeout=4).status != 200)"]
CMD ["uvicorn", "service.app:create_app", "--factory", "--http", "service.protocol:GuardedHttpProtocol", \
     "--timeout-graceful-shutdown", "5", "--host", "0.0.0.0", "--port", "8000"]
