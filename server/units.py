"""The units and up-axis options of the commands and jobs that read captures.

``--units {auto,m,cm,mm}`` and ``--up {auto,y,z}``: the frames are converted to metres with +Y
up on the way in (``engine.mesh_io.units``), everything downstream works in metres, and the
outputs record what the files were in. Lengths for people (residuals, errors) are shown in the
data's units: millimetres for data in metres or millimetres, centimetres for data in
centimetres, each with its share of the model size.
"""

from __future__ import annotations

import numpy as np

from engine.mesh_io import Mesh, resolve_convention, to_metres_y_up
from engine.mesh_io.units import UNITS_PER_METRE, UP_AXES

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
                        help="up axis of the input meshes (default auto: the longer of the body's Y and "
                             "Z extents; else the dataset's metadata); +Z up becomes +Y up, (x, y, z) -> "
                             "(x, z, -y)")


def declared_convention(records):
    """The units and up axis the inputs' metadata agree on.

    Parameters
    ----------
    records : iterable of dict or None   e.g. each sequence's meta.json and its dataset's manifest
                                         ``body``: their "units" ("m", "cm", "mm") and "up"
                                         ("+Y", "+Z") entries; other values are ignored

    Returns
    -------
    units, up : str or None   None where no record says, or the records disagree
    """
    units, up = set(), set()
    for record in records:
        if not isinstance(record, dict):
            continue
        units.add(str(record.get("units", "")).strip().lower())
        up.add(str(record.get("up", "")).strip().lower().lstrip("+"))
    units &= set(UNITS_PER_METRE)  # values it cannot mean are not a claim
    up &= set(UP_AXES)
    return (units.pop() if len(units) == 1 else None), (up.pop() if len(up) == 1 else None)


def meshes_to_metres(meshes, units="auto", up="auto", *, declared=(None, None)):
    """Decide the inputs' units and up axis and convert the meshes to metres, +Y up.

    Parameters
    ----------
    meshes : list of engine.mesh_io.Mesh   all frames of a run (one convention for all)
    units, up : str                        as on the command line ("auto" detects)
    declared : (units, up)                 what the metadata says (:func:`declared_convention`)

    Returns
    -------
    meshes : list of Mesh                  the same list when nothing changes, else new meshes
    convention : engine.mesh_io.Convention
    """
    convention = resolve_convention((m.vertices for m in meshes), units, up, declared_units=declared[0],
                                    declared_up=declared[1])
    if convention.units == "m" and convention.up == "y":
        return meshes, convention
    converted = [Mesh(vertices=to_metres_y_up(m.vertices, convention.units, convention.up), faces=m.faces,
                      colors=m.colors, source=m.source) for m in meshes]
    return converted, convention


def display_unit(convention):
    """The unit lengths are shown in for data in ``convention.units``: "mm" or "cm"."""
    return DISPLAY_UNIT[convention.units]


def length_text(metres, convention, size=None, digits=2):
    """A length for people: in the data's display unit, and in % of ``size`` (metres) if given."""
    unit = display_unit(convention)
    text = f"{float(metres) * DISPLAY_PER_METRE[unit]:.{digits}f} {unit}"
    if size:
        text += f" ({100.0 * float(metres) / size:.3g}% of model size)"
    return text


def convention_record(convention, size=None):
    """JSON record of the inputs' convention: units, up, how each was decided, model size (m)."""
    record = convention.to_metadata()
    record["display_unit"] = display_unit(convention)
    if size is not None and np.isfinite(size):
        record["model_size_m"] = float(size)
    return record


__all__ = ["add_units_arguments", "convention_record", "declared_convention", "display_unit", "length_text",
           "meshes_to_metres"]
