"""HTTP service of the dacrt ray caster: scenes of triangle meshes, queried with ray batches.

Importing the package does nothing but define: the server's start (``app``'s lifespan) chooses
where Numba keeps the compiled kernels (``dacrt.cache.use_cache_dir``). Its modules, by role:

- start and settings: ``cli`` (``dacrt-service``, ``python -m service`` through ``__main__``),
  ``app`` (the ``create_app`` factory), ``settings`` (DACRT_* environment), ``logs``,
  ``warmup`` (every kernel a request reaches), ``children`` (child processes that end with the
  server, even one killed outright), ``protocol`` (uvicorn's HTTP with deadlines), ``allocator``
  (glibc's malloc arenas, capped);
- requests: ``routes`` (thin handlers), ``pipeline`` (the one path of a query or sensor:
  receive, decode, trace, encode, respond), ``options`` (what a query or sensor asks: one record,
  ``?fields=`` read once), ``params`` (path and query parameters), ``deps``
  (dependencies), ``hosts`` (the ``Host`` and ``Origin`` a request may give), ``errors``
  (domain errors -> statuses), ``openapi`` (what the document says of bodies), ``timing``
  (``Server-Timing``), ``responses`` (answers sent as buffers), ``metrics`` (Prometheus),
  ``admission`` (the budget of bytes the requests in flight hold) and ``footprint`` (what a
  request holds at its peak);
- bodies: ``wire`` (every body format; its docstring is the spec), ``sensor_requests`` (the JSON
  bodies of the sensors);
- scenes: ``store`` (immutable snapshots), ``persistence`` (DACRT_DATA_DIR's files),
  ``patterns`` (uploaded lidar scan patterns);
- the engine: ``tracing`` (queries), ``sensing`` (the engine's ``dacrt.sensors`` on a scene
  version: cameras, lidars, rigs), ``shading`` (pictures), ``cluster`` (DACRT_DASK_SCHEDULER);
- clients: ``client`` (NumPy in, NumPy out), ``transport`` (its urllib3 transport),
  ``intersector`` (trimesh's ray interface over HTTP).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("dacrt-service")  # pyproject.toml's, the one place it is written
except PackageNotFoundError:  # sources on sys.path, not installed
    __version__ = "0+unknown"
