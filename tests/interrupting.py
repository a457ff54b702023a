"""Ctrl-C (or SIGTERM, which ``server.cli`` raises as an exception) between any two lines of a writer.

Python takes a signal between bytecodes and raises the handler's exception there; a trace function
that raises at the k-th line event, for every k in turn, puts the exception at every line."""

from __future__ import annotations

import sys


def interrupt_at_every_line(run, files, check, skip=()):
    """Call ``run()`` once per line event in the source ``files``, raising KeyboardInterrupt at
    that line, then once more uninterrupted; ``check(interrupted_line)`` after each call (None
    for the last). ``skip``: (code, line) pairs not interrupted. Returns the number of lines."""
    files = set(files)
    target = 0
    while True:
        target += 1
        seen, at = 0, None

        def local(frame, event, arg):
            nonlocal seen, at
            if event == "line" and (frame.f_code, frame.f_lineno) not in skip:
                seen += 1
                if seen == target:
                    at = (frame.f_code.co_name, frame.f_lineno)
                    raise KeyboardInterrupt
            return local

        sys.settrace(lambda frame, event, arg: local if frame.f_code.co_filename in files else None)
        try:
            run()
        except KeyboardInterrupt:
            pass
        finally:
            sys.settrace(None)
        check(at)
        if at is None:
            return seen
