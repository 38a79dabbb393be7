"""HTTP routes, a few lines each: ``meshes`` (meshes and their scenes), ``queries`` (ray batches),
``ops`` (health, metrics, capabilities)."""
