"""usd-core's validators on USD files: what ``usdchecker`` would run, from Python.

    .venv/bin/python tests/validators/validate_usd.py FILE.usd [FILE.usda ...]

Every validator registered with ``UsdValidation`` except the usdz packaging ones (usd-core 26 has
no Python ``ComplianceChecker`` and its wheel no ``usdchecker`` program). Prints each file's
errors (nothing but ``FILE: no errors`` for a clean one) and exits with 1 when any file has one.
The tests use :func:`validation_errors` (tests/engine/test_export_usd.py).
"""

from __future__ import annotations

import sys


def validation_errors(stage):
    """Errors (strings) of every registered UsdValidation validator but the usdz ones, on ``stage``."""
    from pxr import UsdValidation

    registry = UsdValidation.ValidationRegistry()
    validators = [registry.GetOrLoadValidatorByName(m.name) for m in registry.GetAllValidatorMetadata()
                  if "UsdzValidators" not in m.GetKeywords()]
    if len(validators) <= 10:
        raise RuntimeError(f"only {len(validators)} USD validators are registered: is usd-core complete?")
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    return [e.GetErrorAsString() for e in errors if e.GetType() != UsdValidation.ValidationErrorType.Info]


def main(argv=None):
    from pxr import Tf, Usd

    paths = sys.argv[1:] if argv is None else argv
    if not paths:
        print("usage: validate_usd.py FILE.usd [FILE ...]", file=sys.stderr)
        return 2
    failed = False
    for path in paths:
        try:
            stage = Usd.Stage.Open(path)
        except Tf.ErrorException as exc:  # a missing or unreadable file: USD's error, on one line
            stage, reason = None, " ".join(str(exc).split()).rsplit(" : ", 1)[-1].strip("'\" ")
            print(f"{path}: cannot open it ({reason})")
            failed = True
            continue
        if stage is None:
            print(f"{path}: not a USD stage usd-core can open")
            failed = True
            continue
        errors = validation_errors(stage)
        print(f"{path}: " + ("no errors" if not errors else f"{len(errors)} errors"))
        for error in errors:
            print(f"  {error}")
        failed |= bool(errors)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
