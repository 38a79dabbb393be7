"""HTTP routes, a few lines each: ``meshes`` (meshes and their scenes), ``queries`` (ray batches),
``points`` (point queries: ``/nearest``), ``pictures`` (sensors: ``/render``, ``/camera``,
``/lidar``, rigs: ``/sensors``), ``patterns`` (lidar scan patterns), ``ops`` (the viewer, health,
metrics, capabilities)."""
