"""Output directories written whole or not at all: ``synth`` and ``align`` write into a hidden
staging directory next to ``--out`` and rename it onto ``--out`` when it is complete."""

from __future__ import annotations

import os
import shutil
from contextlib import contextmanager


@contextmanager
def staged(out):
    """``with staged(out) as staging:`` write into ``staging``, a hidden directory next to ``out``
    (``out`` checked first: ``synth.check_dataset_out``, align's checks); it replaces ``out`` when the
    block ends, and is removed on any error (with the parent directories made for it)."""
    made = [p for p in out.absolute().parents if not p.exists()]  # deepest first
    staging = out.with_name(f".{out.name}.partial-{os.getpid()}")
    try:  # made inside the try: a signal taken just after the mkdir removes it too
        if staging.exists():
            shutil.rmtree(staging)
        staging.mkdir(parents=True)
        yield staging
        if out.exists():
            shutil.rmtree(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        for parent in made:  # only the empty ones made here
            try:
                parent.rmdir()
            except OSError:
                break
        raise
