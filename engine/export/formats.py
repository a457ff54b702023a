"""The export formats by name: ``write_export(path, frames, format)`` picks the writer.

=========  ===============================================  =======================
format     what                                             path
=========  ===============================================  =======================
glb        binary glTF 2.0, morph targets + node animation  a file (.glb)
usd        USD, time-sampled points + root transform       .usd / .usdc / .usda
obj, ply   one mesh file per frame + clip.json              a directory, or a .zip
vat        vertex-animation texture (16-bit PNG) + mesh     a directory, or a .zip
=========  ===============================================  =======================
"""

from __future__ import annotations

from pathlib import Path

from engine.export.gltf import glb_bytes
from engine.export.sequence import write_mesh_sequence, write_sequence_zip
from engine.mesh_io.atomic import atomic_write

FORMATS = {"glb": ".glb", "usd": ".usdc", "obj": ".zip", "ply": ".zip", "vat": ".zip"}  # format -> file suffix of a single file


def write_export(path, frames, format, *, progress=None, precision="int16", interpolation="LINEAR"):
    """Write the clip ``frames`` (ClipFrames) to ``path`` as ``format`` (one of ``FORMATS``).

    ``precision`` and ``interpolation`` are the glTF options (engine.export.gltf).
    Returns a dict of figures about what was written (bytes, and the writer's own).
    """
    if format not in FORMATS:
        raise ValueError(f"unknown export format {format!r}; choose one of {', '.join(FORMATS)}")
    path = Path(path)
    stats = {"format": format, "frames": len(frames)}
    if format == "glb":
        data, figures = glb_bytes(frames, precision=precision, interpolation=interpolation)
        with atomic_write(path) as file:
            file.write(data)
        stats.update(figures)
        if progress is not None:
            progress(len(frames), len(frames))
    elif format == "usd":
        from engine.export.usd import write_usd

        stats.update(write_usd(path, frames, progress=progress))
    elif format == "vat":
        from engine.export.vat import write_vat

        record = write_vat(path, frames, progress=progress)
        stats.update(max_error_m=record["max_error_m"], width=record["width"], height=record["height"])
        if path.is_dir():
            stats["bytes"] = sum(p.stat().st_size for p in path.iterdir())
            return stats
    elif path.suffix.lower() == ".zip":
        write_sequence_zip(path, frames, format, progress=progress)
    else:
        write_mesh_sequence(path, frames, format, progress=progress)
        stats["bytes"] = sum(p.stat().st_size for p in path.iterdir())
        return stats
    stats["bytes"] = path.stat().st_size
    return stats
