"""The rows of a PLY file's elements: binary (either byte order; fixed- and variable-length lists)
and ascii, each checked against the header's counts and types (a truncated or malformed body gets
a ``MeshFormatError`` naming the element and row). ``engine.mesh_io.ply`` parses the header and
builds the mesh from what these return."""

from __future__ import annotations

import struct

import numpy as np

from .errors import MeshFormatError


def read_binary_element(data, offset, element, source):
    """Decode one binary element.

    Returns
    -------
    values : dict   property name -> (count,) array, or for a list property a tuple
        ((total,) items, (count,) int64 list lengths)
    offset : int    first byte after the element
    """
    properties = element.properties
    if all(p.count_dtype is None for p in properties):
        row = np.dtype([(f"p{i}", p.dtype) for i, p in enumerate(properties)])
        _require(data, offset, row.itemsize * element.count, element, source)
        table = np.frombuffer(data, dtype=row, count=element.count, offset=offset)
        values = {p.name: table[f"p{i}"] for i, p in enumerate(properties)}
        return values, offset + row.itemsize * element.count
    fixed = _read_binary_fixed_lists(data, offset, element)
    if fixed is not None:
        return fixed
    return _read_binary_variable_lists(data, offset, element, source)


def _read_binary_fixed_lists(data, offset, element):
    """Fast path: every row's lists as long as the first row's (all triangles, all quads).

    Returns None when the guess does not hold.
    """
    if element.count == 0:
        return {p.name: _empty(p) for p in element.properties}, offset
    fields, lengths, position = [], {}, offset
    for i, p in enumerate(element.properties):
        if p.count_dtype is None:
            fields.append((f"p{i}", p.dtype))
            position += p.dtype.itemsize
            continue
        if position + p.count_dtype.itemsize > len(data):
            return None
        length = int(np.frombuffer(data, p.count_dtype, 1, position)[0])
        if length < 0:
            return None
        lengths[i] = length
        fields += [(f"c{i}", p.count_dtype), (f"p{i}", p.dtype, (length,))]
        position += p.count_dtype.itemsize + length * p.dtype.itemsize
    row = np.dtype(fields)
    size = row.itemsize * element.count
    if offset + size > len(data):
        return None
    table = np.frombuffer(data, dtype=row, count=element.count, offset=offset)
    if any((table[f"c{i}"] != length).any() for i, length in lengths.items()):
        return None
    values = {}
    for i, p in enumerate(element.properties):
        if p.count_dtype is None:
            values[p.name] = table[f"p{i}"]
        else:
            counts = np.full(element.count, lengths[i], dtype=np.int64)
            values[p.name] = (table[f"p{i}"].reshape(-1), counts)
    return values, offset + size


def _read_binary_variable_lists(data, offset, element, source):
    """General path: walk the rows in Python to find each list's length, then gather."""
    properties = element.properties
    count_formats = [
        None if p.count_dtype is None else _struct_format(p.count_dtype) for p in properties
    ]
    starts = [np.empty(element.count, dtype=np.int64) for _ in properties]
    lengths = [np.zeros(element.count, dtype=np.int64) for _ in properties]
    position, size = offset, len(data)
    for row in range(element.count):
        for i, p in enumerate(properties):
            if p.count_dtype is None:
                starts[i][row] = position
                position += p.dtype.itemsize
                continue
            if position + p.count_dtype.itemsize > size:
                _raise_truncated(element, row, source)
            length = struct.unpack_from(count_formats[i], data, position)[0]
            if length < 0:
                raise MeshFormatError(
                    f"{source}: element '{element.name}' row {row} has a negative list length"
                )
            position += p.count_dtype.itemsize
            starts[i][row], lengths[i][row] = position, length
            position += length * p.dtype.itemsize
        if position > size:
            _raise_truncated(element, row, source)
    codes = np.frombuffer(data, dtype=np.uint8)
    values = {}
    for i, p in enumerate(properties):
        width = p.dtype.itemsize
        if p.count_dtype is None:
            item_offsets = starts[i]
        else:
            first_item = np.cumsum(lengths[i]) - lengths[i]
            rank = np.arange(lengths[i].sum()) - np.repeat(first_item, lengths[i])
            item_offsets = np.repeat(starts[i], lengths[i]) + rank * width
        raw = codes[item_offsets[:, None] + np.arange(width)]
        items = np.ascontiguousarray(raw).view(p.dtype).reshape(-1)
        values[p.name] = items if p.count_dtype is None else (items, lengths[i])
    return values, position


def read_ascii_element(tokens, position, element, source):
    """Decode one ascii element from the body's token list (values as float64).

    Returns
    -------
    values : dict   as for `read_binary_element`
    position : int  index of the first token after the element
    """
    properties = element.properties
    n_rows = element.count
    if n_rows == 0:
        return {p.name: _empty(p) for p in properties}, position
    # Where each property's value(s) start within a row, assuming every row is as long as the
    # first; verified below, with a row-by-row walk when it does not hold.
    layout, cursor = [], position
    for p in properties:
        if p.count_dtype is None:
            layout.append((cursor - position, None))
            cursor += 1
        else:
            length = _ascii_int(tokens, cursor, element, source)
            if length < 0:
                return _read_ascii_rows(tokens, position, element, source)
            layout.append((cursor - position, length))
            cursor += 1 + length
    row_length = cursor - position
    end = position + row_length * n_rows
    if end <= len(tokens):
        table = _ascii_numbers(tokens[position:end], element, source).reshape(n_rows, row_length)
        if all(length is None or (table[:, at] == length).all() for at, length in layout):
            values = {}
            for p, (at, length) in zip(properties, layout):
                if length is None:
                    values[p.name] = table[:, at]
                else:
                    items = table[:, at + 1 : at + 1 + length].reshape(-1)
                    values[p.name] = (items, np.full(n_rows, length, dtype=np.int64))
            return values, end
    return _read_ascii_rows(tokens, position, element, source)


def _read_ascii_rows(tokens, position, element, source):
    properties = element.properties
    starts = [np.empty(element.count, dtype=np.int64) for _ in properties]
    lengths = [np.zeros(element.count, dtype=np.int64) for _ in properties]
    begin = position
    for row in range(element.count):
        for i, p in enumerate(properties):
            if p.count_dtype is None:
                starts[i][row] = position
                position += 1
            else:
                length = _ascii_int(tokens, position, element, source)
                if length < 0:
                    raise MeshFormatError(
                        f"{source}: element '{element.name}' row {row} has a negative list length"
                    )
                starts[i][row], lengths[i][row] = position + 1, length
                position += 1 + length
    if position > len(tokens):
        _raise_truncated(element, element.count - 1, source)
    numbers = _ascii_numbers(tokens[begin:position], element, source)
    values = {}
    for i, p in enumerate(properties):
        if p.count_dtype is None:
            values[p.name] = numbers[starts[i] - begin]
        else:
            first_item = np.cumsum(lengths[i]) - lengths[i]
            rank = np.arange(lengths[i].sum()) - np.repeat(first_item, lengths[i])
            at = np.repeat(starts[i] - begin, lengths[i]) + rank
            values[p.name] = (numbers[at], lengths[i])
    return values, position


def _ascii_int(tokens, position, element, source):
    if position >= len(tokens):
        raise MeshFormatError(
            f"{source}: file ends inside element '{element.name}' (truncated or wrong counts)"
        )
    try:
        return int(tokens[position])
    except ValueError:
        shown = tokens[position][:30].decode("utf-8", "replace")
        raise MeshFormatError(
            f"{source}: element '{element.name}': list length {shown!r} is not an integer"
        ) from None


def _ascii_numbers(tokens, element, source):
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        for token in tokens:
            try:
                float(token)
            except ValueError:
                shown = token[:30].decode("utf-8", "replace")
                raise MeshFormatError(
                    f"{source}: element '{element.name}': {shown!r} is not a number"
                ) from None
        raise  # pragma: no cover


def _empty(p):
    if p.count_dtype is None:
        return np.empty(0, dtype=p.dtype)
    return np.empty(0, dtype=p.dtype), np.empty(0, dtype=np.int64)


def _struct_format(dtype):
    return ("<" if dtype.byteorder in "<=|" else ">") + dtype.char


def _require(data, offset, size, element, source):
    if offset + size > len(data):
        raise MeshFormatError(
            f"{source}: truncated: element '{element.name}' needs {size} bytes, "
            f"only {max(len(data) - offset, 0)} remain"
        )


def _raise_truncated(element, row, source):
    raise MeshFormatError(
        f"{source}: truncated: the file ends inside row {row} of element '{element.name}' "
        f"({element.count} rows declared)"
    )
