"""HTTP service of the dacrt ray caster: scenes of triangle meshes, queried with ray batches.

Modules, in dependency order: ``errors`` (domain errors -> statuses), ``settings`` (DACRT_*
environment), ``wire`` (body formats; its docstring is the spec), ``store`` (scenes as immutable
snapshots), ``tracing`` (the only caller of the engine), ``metrics``, ``deps`` and ``timing``
(request plumbing), ``routes`` (thin handlers), ``app`` (the ``create_app`` factory), ``client``.
"""

__version__ = "0.1.0"
