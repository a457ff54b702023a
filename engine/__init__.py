"""morphspace engine: pure computation on meshes and mesh sequences (no server imports)."""
