"""The units and up-axis options of the commands and jobs that read captures.

``--units {auto,m,cm,mm}`` and ``--up {auto,y,z}``: each sequence's frames are converted to
metres with +Y up on the way in (``engine.mesh_io.units``; a dataset may mix sequences in
different units), everything downstream works in metres, and the outputs record what the files
were in. Lengths for people (residuals, errors) are shown in the data's units: millimetres for
data in metres or millimetres, centimetres for data in centimetres (millimetres when the
sequences differ), each with its share of the model size.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

from engine.mesh_io import Mesh, resolve_convention, to_metres_y_up
from engine.mesh_io.units import UNITS_PER_METRE, UP_AXES, Convention

UNITS_CHOICES = ("auto", "m", "cm", "mm")
UP_CHOICES = ("auto", "y", "z")
DISPLAY_UNIT = {"m": "mm", "cm": "cm", "mm": "mm"}
DISPLAY_PER_METRE = {"mm": 1000.0, "cm": 100.0}


def add_units_arguments(parser):
    """``--units`` and ``--up`` (both default ``auto``)."""
    parser.add_argument("--units", choices=UNITS_CHOICES, default="auto",
                        help="length unit of the input meshes (default auto: from the model's size, a "
                             "person being 0.5-2.5 m across; else the dataset's metadata)")
    parser.add_argument("--up", choices=UP_CHOICES, default="auto",
                        help="up axis of the input meshes (default auto: the axis along which the subject "
                             "keeps to a floor, else the longer of the body's Y and Z extents, else the "
                             "dataset's metadata); +Z up becomes +Y up, (x, y, z) -> "
                             "(x, z, -y)")


class Declared(NamedTuple):
    """What the metadata says: ``units`` ("m", "cm", "mm") and ``up`` ("y", "z"), None where no
    record says; ``ignored``: one line per value that is neither (it is not a claim)."""

    units: str | None
    up: str | None
    ignored: tuple = ()


def declared_convention(records):
    """The units and up axis the metadata says, the first record that says each winning.

    Parameters
    ----------
    records : iterable of dict or None   most specific first, e.g. a sequence's meta.json, then
                                         its dataset manifest's ``body``: their "units" ("m",
                                         "cm", "mm") and "up" ("+Y", "+Z"); other values are
                                         not a claim, and are named in ``ignored``

    Returns
    -------
    Declared   (units, up, ignored)
    """
    units = up = None
    ignored = []
    for record in records:
        if not isinstance(record, dict):
            continue
        said_units = str(record.get("units", "")).strip().lower()
        said_up = str(record.get("up", "")).strip().lower().lstrip("+")
        if said_units and said_units not in UNITS_PER_METRE:
            ignored.append(f"the metadata's units {record.get('units')!r} are none of m, cm, mm: ignored")
        if said_up and said_up not in UP_AXES:
            ignored.append(f"the metadata's up axis {record.get('up')!r} is neither +Y nor +Z: ignored")
        units = units or (said_units if said_units in UNITS_PER_METRE else None)
        up = up or (said_up if said_up in UP_AXES else None)
    return Declared(units, up, tuple(ignored))


def decide_convention(frames, units="auto", up="auto", declared=Declared(None, None)):
    """``engine.mesh_io.resolve_convention`` of ``frames`` with what the metadata says
    (``declared``, :func:`declared_convention`); the metadata values it ignored are added to the
    warnings."""
    convention = resolve_convention(frames, units, up, declared_units=declared.units, declared_up=declared.up)
    return replace(convention, warnings=convention.warnings + declared.ignored) if declared.ignored else convention


def meshes_to_metres(meshes, units="auto", up="auto", *, declared=Declared(None, None)):
    """Decide the inputs' units and up axis and convert the meshes to metres, +Y up.

    Parameters
    ----------
    meshes : list of engine.mesh_io.Mesh   all frames of a run (one convention for all)
    units, up : str                        as on the command line ("auto" detects)
    declared : Declared                    what the metadata says (:func:`declared_convention`)

    Returns
    -------
    meshes : list of Mesh                  the same list when nothing changes, else new meshes
    convention : engine.mesh_io.Convention
    """
    convention = decide_convention((m.vertices for m in meshes), units, up, declared)
    if convention.units == "m" and convention.up == "y":
        return meshes, convention
    converted = [Mesh(vertices=to_metres_y_up(m.vertices, convention.units, convention.up), faces=m.faces,
                      colors=m.colors, source=m.source) for m in meshes]
    return converted, convention


def display_unit(convention):
    """The unit lengths are shown in for data in ``convention.units``: "mm" or "cm"."""
    return DISPLAY_UNIT[convention.units]


def common_convention(conventions):
    """One convention for reporting a run over several sequences: theirs when they all agree on
    units and up axis, else metres, +Y up (lengths then in mm)."""
    conventions = list(conventions)
    if conventions and all((c.units, c.up) == (conventions[0].units, conventions[0].up) for c in conventions):
        return conventions[0]
    return Convention(units="m", up="y", units_from="mixed", up_from="mixed")


def source_metadata(names, conventions, rest=None):
    """What the inputs were in, for the metadata of what is made from them (a motion space).

    Parameters
    ----------
    names : list of str                       one per source
    conventions : list of engine.mesh_io.Convention   one per source
    rest : Convention or None                 the rest shape's, recorded as input "rest"

    Returns
    -------
    dict   ``source_units`` and ``source_up``: the sources' own ("mm", "+Z", ...) when they all
           agree, else "mixed"; ``input``: {name: units, up, units_from, up_from}
    """
    common = common_convention(conventions)
    inputs = {name: c.to_metadata() for name, c in zip(names, conventions)}
    if rest is not None:
        inputs["rest"] = rest.to_metadata()
    return {"source_units": common.units if common.units_from != "mixed" else "mixed",
            "source_up": common.up_label if common.up_from != "mixed" else "mixed", "input": inputs}


def say_conventions(conventions, names, say, what="input"):
    """Tell ``say(line)`` what each sequence is in: one line per group of sequences decided alike,
    then every warning, named after its sequence."""
    groups = {}
    for name, convention in zip(names, conventions):
        key = (convention.units, convention.up, convention.units_from, convention.up_from)
        groups.setdefault(key, []).append((name, convention))
    for members in groups.values():
        first = members[0][1]
        listed = ", ".join(name for name, _ in members[:4]) + (f" and {len(members) - 4} more" if len(members) > 4
                                                               else "")
        converted = "" if (first.units, first.up) == ("m", "y") else "; converted to metres, +Y up"
        say(f"{what} {listed}: {first.describe()}{converted}")
    for name, convention in zip(names, conventions):
        for warning in convention.warnings:
            say(f"warning: {name}: {warning}")


def count_text(n, noun):
    """"1 frame", "2 frames"."""
    return f"{n} {noun}{'s' * (n != 1)}"


def figure_text(value, digits=2):
    """``value`` with ``digits`` decimals, or 3 significant figures when it is under 1, so that a
    figure is never shown as 0.00 unless it is 0 (``0.00173``); NaN as ``nan``."""
    value = float(value)
    if math.isfinite(value) and 0 < abs(value) < 1:
        digits = max(digits, 2 - math.floor(math.log10(abs(value))))
    return f"{value:.{digits}f}"


def length_text(metres, convention, size=None, digits=2):
    """A length for people: in the data's display unit, and in % of ``size`` (metres) if given.

    ``digits`` decimals, or 3 significant figures for a length under 1 display unit, so that a
    length is never shown as 0.00 unless it is 0 (metres read as centimetres: ``0.00173 cm``)."""
    unit = display_unit(convention)
    value = float(metres) * DISPLAY_PER_METRE[unit]
    text = f"{figure_text(value, digits)} {unit}"
    if size:
        text += f" ({100.0 * float(metres) / size:.3g}% of model size)"
    return text


__all__ = ["add_units_arguments", "common_convention", "count_text", "declared_convention", "display_unit",
           "figure_text", "length_text", "meshes_to_metres", "say_conventions"]
