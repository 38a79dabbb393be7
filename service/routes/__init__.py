"""HTTP routes, a few lines each: ``scenes`` (meshes and scenes), ``queries`` (ray batches),
``ops`` (health, metrics, capabilities)."""
