"""Output directories written whole or not at all: ``synth`` and ``align`` write into a hidden
staging directory next to ``--out`` and rename it onto ``--out`` when it is complete."""

from __future__ import annotations

import os
import shutil
from contextlib import contextmanager


def staging_directory(out):
    """The hidden directory next to ``out`` to write into (renamed onto ``out`` when complete);
    ``out`` was checked first (``synth.check_dataset_out``, align's checks). Named here, made by
    ``make_staging``."""
    return out.with_name(f".{out.name}.partial-{os.getpid()}")


def make_staging(staging):
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)


def publish(staging, out):
    """Replace ``out`` by the completed staging directory."""
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    os.replace(staging, out)


@contextmanager
def staged(out):
    """``with staged(out) as staging:`` write into ``staging`` (``staging_directory``; ``out`` checked
    first); published onto ``out`` when the block ends, removed on any error (with the parent
    directories made for it)."""
    made = [p for p in out.absolute().parents if not p.exists()]  # deepest first
    staging = staging_directory(out)
    try:  # made inside the try: a signal taken just after the mkdir removes it too
        make_staging(staging)
        yield staging
        publish(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        for parent in made:  # only the empty ones made here
            try:
                parent.rmdir()
            except OSError:
                break
        raise
