"""Checks of the command line's inputs and outputs, shared by its commands: numbers in a range,
output paths that can be written where the user said (before any work), sequences' meta.json."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

MAX_FPS = 1000.0  # frame rates are in (0, MAX_FPS], as uploads take them (docs/rest.md)


def check_number(value, what, low, high, *, integer=False, above=False, unit=""):
    """``value`` if it is a number (an int when ``integer``; never a bool) from ``low`` to ``high``
    (above ``low`` when ``above``) and finite, else a ValueError: "``what`` must be ..., got ..."."""
    if integer:
        good = isinstance(value, int) and not isinstance(value, bool) and low <= value <= high
        accepted = f"an integer from {low} to {high}"
    else:
        good = (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
                and (low < value if above else low <= value) and value <= high)
        accepted = f"a number {'above' if above else 'from'} {low:g} {'and at most' if above else 'to'} {high:g}"
    if not good:
        raise ValueError(f"{what} must be {accepted}{' ' + unit if unit else ''}, got {value!r}")
    return value


def check_output_file(out, option="--out", inputs=()):
    """Refuse an output file path before any work: an existing directory, a path below a file, or
    one of the ``inputs`` (replacing it would destroy what the output is made from)."""
    out = Path(out)
    named = f"{option} {out}" if option else str(out)
    if out.is_dir():
        raise ValueError(f"{named} is a directory, not a file: name the file to write")
    parent = next((p for p in out.parents if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise ValueError(f"{named}: {parent} is a file, not a directory")
    target = out.resolve()
    for path in inputs:
        if path is not None and Path(path).resolve() == target:
            raise ValueError(f"{named} is the input {path}: name another output file")


def check_output_path(path, option, *, directory=False):
    """Refuse (a ValueError naming ``option`` and ``path``) an output that cannot be written where the user
    said: a directory where a file is wanted, something else where a directory is (``directory``), a parent
    that is a file, or a parent directory not writable. Nothing is created."""
    if directory:
        if path.exists() and not path.is_dir():
            raise ValueError(f"{option} {path}: exists and is not a directory")
    elif path.is_dir():
        raise ValueError(f"{option} {path}: is a directory; give a file name")
    for parent in path.parents:  # (a relative path ends at ".", which exists)
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"{option} {path}: {parent} is not a directory")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise ValueError(f"{option} {path}: cannot write in {parent} (permission denied)")
            break


def read_meta(directory):
    """A sequence directory's meta.json as a dict, checked: an object with an optional ``name``
    (a string), ``fps`` (a number in (0, MAX_FPS]) and ``cyclic`` (a boolean)."""
    meta_path = Path(directory) / "meta.json"
    try:
        meta = json.loads(meta_path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{meta_path}: not valid JSON: {exc}") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{meta_path}: not a JSON object")
    if "name" in meta and (not isinstance(meta["name"], str) or not meta["name"]):
        raise ValueError(f"{meta_path}: name must be a non-empty string, got {meta['name']!r}")
    if "fps" in meta:
        check_number(meta["fps"], f"{meta_path}: fps", 0.0, MAX_FPS, above=True, unit="frames/s")
    if "cyclic" in meta and not isinstance(meta["cyclic"], bool):
        raise ValueError(f"{meta_path}: cyclic must be true or false, got {meta['cyclic']!r}")
    return meta
