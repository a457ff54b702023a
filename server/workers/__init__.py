"""Serving from several processes: ``morphspace serve --workers N`` (see supervisor.py)."""
