"""HTTP service of the dacrt ray caster: scenes of triangle meshes, queried with ray batches.

Modules, in dependency order: ``cache`` (where Numba keeps compiled kernels), ``errors`` (domain
errors -> statuses), ``settings`` (DACRT_* environment), ``wire`` (body formats; its docstring is
the spec), ``store`` (scenes as immutable snapshots), ``persistence`` (the scenes' files),
``tracing`` (the only caller of the engine), ``warmup`` (every kernel a request reaches),
``metrics``, ``logs``, ``deps`` and ``timing`` (request plumbing), ``routes`` (thin handlers),
``app`` (the ``create_app`` factory), ``cli`` (``dacrt-service``), ``client``.
"""

from .cache import use_cache_dir

__version__ = "0.1.0"

#: Numba's compiled kernels, set before anything imports ``dacrt`` (see ``service.cache``).
CACHE_DIR = use_cache_dir()
