"""morphspace server: CLI, REST and WebSocket streaming on top of the engine."""
