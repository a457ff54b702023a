"""REST routes under /v1 (thin: they call the registry, the engine or the job service)."""
