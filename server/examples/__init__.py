"""Runnable examples of using morphspace from other programs."""
