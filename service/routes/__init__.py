"""HTTP routes, a few lines each: ``meshes`` (meshes and their scenes), ``queries`` (ray batches),
``pictures`` (sensors: ``/render``, ``/camera``, ``/lidar``), ``ops`` (the viewer, health,
metrics, capabilities)."""
