"""The names a user gives things that become file or array names (spaces, graphs, datasets,
sequences, graph nodes): letters, digits, ``_``, ``-``, ``.``, at most 128, starting with a
letter or digit, and no ``..`` (so a name is never a path elsewhere)."""

from __future__ import annotations

import re

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")


def is_name(name):
    """Whether ``name`` is such a name."""
    return isinstance(name, str) and NAME.match(name) is not None and ".." not in name


__all__ = ["NAME", "is_name"]
