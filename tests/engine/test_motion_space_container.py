"""Tests for engine.motion_space.container: the memory-mapped `.mspace` array container."""

from __future__ import annotations

import ast
import gc
import json
import mmap
import os
import pickle
import re
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from engine.motion_space import (
    Container,
    MissingArrayError,
    MotionSpaceError,
    inspect_container,
    write_container,
)
from engine.motion_space import container as container_module
from engine.motion_space import container_write

PACKAGE_DIR = Path(container_module.__file__).parent


def sample_arrays():
    """Arrays of every storable kind, including awkward shapes and byte orders."""
    return {
        "scalar": np.array(2.5),
        "empty": np.zeros((0, 3), dtype=np.float32),
        "flags": np.array([True, False, True]),
        "bytes": np.arange(7, dtype=np.uint8),
        "faces": np.arange(12, dtype=np.int32).reshape(4, 3),
        "sources/walk": np.linspace(0, 1, 30, dtype=np.float32).reshape(2, 5, 3),
        "weights.ref": np.array([[1.0, 0.0], [0.5, 0.5]]),
        "big_endian": np.arange(5, dtype=">f8"),
        "int64": np.array([-(2**62), 0, 2**62]),
        "uint64": np.array([2**64 - 1], dtype=np.uint64),
        "half": np.array([1.5, -2.0], dtype=np.float16),
        "complex": np.array([1 + 2j], dtype=np.complex64),
        "strided": np.arange(20, dtype=np.int16).reshape(4, 5)[:, ::2],
        "fortran": np.asfortranarray(np.arange(6, dtype=np.float32).reshape(2, 3)),
    }


def walk_bases(array):
    """The chain of objects behind an array view: array.base, ..., a memoryview's object."""
    chain, obj = [], array
    while obj is not None:
        obj = obj.obj if isinstance(obj, memoryview) else getattr(obj, "base", None)
        if obj is not None:
            chain.append(obj)
    return chain


@pytest.fixture
def space_file(tmp_path):
    metadata = {"name": "walk-jog", "epsilon_mm": 2.5, "sources": [{"name": "walk", "fps": 30}]}
    return write_container(tmp_path / "demo.mspace", sample_arrays(), metadata)


def read_bytes(path):
    return bytearray(Path(path).read_bytes())


# --------------------------------------------------------------------------------------------
# Exact facts first


def test_round_trip_gives_back_every_array_exactly(space_file):
    expected = sample_arrays()
    with Container.open(space_file) as container:
        assert container.names == tuple(expected)
        for name, array in expected.items():
            loaded = container[name]
            assert loaded.shape == array.shape, name
            assert loaded.dtype == array.dtype.newbyteorder("<"), name
            assert loaded.dtype.byteorder in "<|=", name
            np.testing.assert_array_equal(loaded, array, err_msg=name)
            assert container.nbytes(name) == array.nbytes
            assert container.shape(name) == array.shape
        assert container["scalar"].ndim == 0 and container["scalar"][()] == 2.5
        assert container["uint64"][0] == 2**64 - 1
        assert container["empty"].shape == (0, 3) and container.nbytes("empty") == 0


def test_metadata_round_trips(tmp_path):
    metadata = {
        "name": "gaits", "unicode": "vitesse \u00e9lev\u00e9e \u2192 \U0001f3c3",
        "epsilon": 1e-3, "tiny": 5e-324, "huge_int": 2**80, "flag": False, "nothing": None,
        "params": [{"name": "speed", "unit": "m/s", "range": [0.5, 3.0]}],
        "nested": {"a": {"b": [1, [2, [3]]]}}, "empty": {},
    }
    path = write_container(tmp_path / "m.mspace", {}, metadata)
    with Container.open(path) as container:
        assert container.metadata == metadata
        assert container.names == () and len(container) == 0


def test_a_large_header_pushes_the_arrays_further(tmp_path):
    metadata = {"notes": ["x" * 1000] * 100}
    path = write_container(tmp_path / "m.mspace", {"a": np.arange(3), "b": np.ones(2)}, metadata)
    summary = inspect_container(path)
    assert summary["arrays"]["a"]["offset"] == -(-(36 + summary["header_bytes"]) // 64) * 64
    with Container.open(path) as container:
        assert container.metadata == {"notes": ["x" * 1000] * 100}
        assert container["a"].tolist() == [0, 1, 2]


STORABLE_DTYPES = st.sampled_from(
    ["|b1", "|u1", "|i1", "<u2", ">i2", "<u4", ">i4", "<u8", ">i8", "<f2", ">f4", "<f8", ">c16"]
)


@settings(max_examples=40, deadline=None)
@given(
    arrays=st.dictionaries(
        st.from_regex(r"[A-Za-z0-9_./-]{1,12}", fullmatch=True),
        STORABLE_DTYPES.flatmap(
            lambda dtype: hnp.arrays(dtype, hnp.array_shapes(min_dims=0, max_dims=3, min_side=0,
                                                             max_side=4))
        ),
        max_size=4,
    )
)
def test_any_storable_arrays_round_trip(tmp_path_factory, arrays):
    path = write_container(tmp_path_factory.mktemp("h") / "p.mspace", arrays, {"n": len(arrays)})
    with Container.open(path) as container:
        assert container.names == tuple(arrays)
        for name, array in arrays.items():
            loaded = container[name]
            assert loaded.shape == array.shape and loaded.dtype == array.dtype.newbyteorder("<")
            assert loaded.tobytes() == array.astype(loaded.dtype).tobytes()  # NaN-safe


def test_metadata_tuples_and_numpy_scalars_become_plain_json(tmp_path):
    metadata = {"pair": (1, 2), "f": np.float32(0.5), "i": np.int64(7), "b": np.bool_(True)}
    path = write_container(tmp_path / "m.mspace", {}, metadata)
    loaded = Container.open(path).metadata
    assert loaded == {"pair": [1, 2], "f": 0.5, "i": 7, "b": True}
    assert type(loaded["i"]) is int and type(loaded["b"]) is bool


def test_arrays_are_read_only_views_onto_a_memory_map(space_file):
    with Container.open(space_file) as container:
        faces = container["faces"]
        assert faces.flags.writeable is False
        assert any(isinstance(obj, mmap.mmap) for obj in walk_bases(faces))
        with pytest.raises(ValueError):
            faces[0, 0] = 1
        with pytest.raises(ValueError):
            faces.flags.writeable = True


def test_every_array_starts_on_a_64_byte_boundary(space_file):
    summary = inspect_container(space_file)
    offsets = [entry["offset"] for entry in summary["arrays"].values()]
    assert offsets and all(offset % 64 == 0 for offset in offsets)
    assert summary["file_size"] % 64 == 0
    assert summary["file_size"] == space_file.stat().st_size
    with Container.open(space_file) as container:
        for name in container:
            if container.nbytes(name):
                assert container[name].ctypes.data % 64 == 0, name


def test_byte_layout_matches_the_documentation(space_file):
    raw = space_file.read_bytes()
    magic, version, header_length = struct.unpack_from("<8sIQ", raw)
    assert magic == b"\x89MSPACE\n" and version == 1
    header = json.loads(raw[36:36 + header_length])
    assert header["format"] == "morphspace-motion-space"
    assert header["checksum_algorithm"] == "blake2b-128"
    assert header["file_size"] == len(raw)
    entry = header["arrays"]["faces"]
    assert entry == {"dtype": "<i4", "shape": [4, 3], "offset": entry["offset"], "nbytes": 48,
                     "checksum": entry["checksum"]}
    data = raw[entry["offset"]:entry["offset"] + 48]
    assert data == np.arange(12, dtype="<i4").tobytes()
    import hashlib

    assert hashlib.blake2b(data, digest_size=16).hexdigest() == entry["checksum"]
    assert hashlib.blake2b(raw[:20] + raw[36:36 + header_length],
                           digest_size=16).digest() == raw[20:36]
    assert set(raw[36 + header_length:min(e["offset"] for e in header["arrays"].values())]) <= {0}


def test_inspect_summarises_without_mapping(space_file):
    summary = inspect_container(space_file)
    json.dumps(summary)  # JSON-serialisable for the CLI
    assert summary["path"] == str(space_file)
    assert summary["metadata"]["name"] == "walk-jog"
    assert summary["arrays"]["faces"]["shape"] == [4, 3]
    assert list(summary["arrays"]) == list(sample_arrays())
    assert len(summary["header_checksum"]) == 32


def test_missing_array_is_a_key_error_listing_the_names(space_file):
    with Container.open(space_file) as container:
        with pytest.raises(MissingArrayError) as caught:
            container["nope"]
        message = str(caught.value)
        assert message.startswith(str(space_file)) and "'nope'" in message and "'faces'" in message
        assert isinstance(caught.value, KeyError) and isinstance(caught.value, MotionSpaceError)
        assert "nope" not in container and "faces" in container
        assert container.get("nope") is None


def test_containers_compare_by_identity(space_file):
    first, second = Container.open(space_file), Container.open(space_file)
    assert first == first and first != second and len({first, second}) == 2
    assert repr(first).startswith(f"<Container {str(space_file)!r} (14 arrays")


def test_views_stay_valid_after_close(space_file):
    container = Container.open(space_file)
    faces = container["faces"]
    container.close()
    container.close()  # idempotent
    assert container.closed
    np.testing.assert_array_equal(faces, np.arange(12).reshape(4, 3))
    with pytest.raises(MotionSpaceError, match="closed"):
        container["faces"]


def test_close_without_views_releases_the_map(space_file):
    container = Container.open(space_file)
    mapping = container._mmap
    container.close()
    assert mapping.closed


def test_open_keeps_mapping_valid_when_the_file_is_replaced(space_file):
    with Container.open(space_file) as container:
        write_container(space_file, {"other": np.ones(3)}, {})
        np.testing.assert_array_equal(container["faces"], np.arange(12).reshape(4, 3))
    assert Container.open(space_file).names == ("other",)


# --------------------------------------------------------------------------------------------
# Atomic writing


def test_failure_mid_write_keeps_the_old_file_and_leaves_no_temporary(space_file, monkeypatch):
    before = space_file.read_bytes()
    original = container_write._array_chunks
    calls = []

    def failing_chunks(array, dtype):
        calls.append(array.shape)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        yield from original(array, dtype)

    monkeypatch.setattr(container_write, "_array_chunks", failing_chunks)
    with pytest.raises(OSError, match="No space"):
        write_container(space_file, sample_arrays(), {"new": True})
    assert space_file.read_bytes() == before
    assert sorted(p.name for p in space_file.parent.iterdir()) == ["demo.mspace"]


def test_interrupt_before_rename_keeps_the_old_file(space_file, monkeypatch):
    before = space_file.read_bytes()

    def interrupted_fsync(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(container_write.os, "fsync", interrupted_fsync)
    with pytest.raises(KeyboardInterrupt):
        write_container(space_file, {"x": np.zeros(10)}, {})
    monkeypatch.undo()
    assert space_file.read_bytes() == before
    assert [p.name for p in space_file.parent.iterdir()] == ["demo.mspace"]


def test_write_creates_parents_and_returns_the_path(tmp_path):
    path = write_container(str(tmp_path / "a" / "b" / "s.mspace"), {"x": [1, 2, 3]}, {})
    assert path == tmp_path / "a" / "b" / "s.mspace"
    assert Container.open(path)["x"].tolist() == [1, 2, 3]


def test_large_arrays_are_streamed_in_chunks(tmp_path, monkeypatch):
    monkeypatch.setattr(container_write, "_CHUNK_BYTES", 1000)
    array = np.arange(3000, dtype=">i8").reshape(100, 30)  # converted one chunk at a time
    path = write_container(tmp_path / "c.mspace", {"a": array, "b": array[::-1].T}, {})
    with Container.open(path) as container:
        np.testing.assert_array_equal(container["a"], array)
        np.testing.assert_array_equal(container["b"], array[::-1].T)


# --------------------------------------------------------------------------------------------
# Damaged and foreign files


@pytest.mark.parametrize("cut", ["magic", "preamble", "header", "padding", "array", "last_byte"])
def test_truncated_file_says_truncated(space_file, cut):
    raw = space_file.read_bytes()
    header_length = struct.unpack_from("<Q", raw, 12)[0]
    faces_offset = inspect_container(space_file)["arrays"]["faces"]["offset"]
    keep = {"magic": 4, "preamble": 20, "header": 36 + header_length // 2,
            "padding": 36 + header_length + 1, "array": faces_offset + 10,
            "last_byte": len(raw) - 1}[cut]
    space_file.write_bytes(raw[:keep])
    with pytest.raises(MotionSpaceError, match="truncated") as caught:
        Container.open(space_file, verify=False)
    assert str(caught.value).startswith(str(space_file))
    with pytest.raises(MotionSpaceError, match="truncated"):
        inspect_container(space_file)


def test_truncation_message_gives_both_sizes(space_file):
    raw = space_file.read_bytes()
    space_file.write_bytes(raw[:-64])
    with pytest.raises(MotionSpaceError) as caught:
        Container.open(space_file)
    assert str(caught.value) == (
        f"{space_file}: truncated: header says {len(raw)} bytes, file has {len(raw) - 64}"
    )


def test_trailing_data_is_refused(space_file):
    with open(space_file, "ab") as file:
        file.write(b"junk")
    with pytest.raises(MotionSpaceError, match="trailing data"):
        Container.open(space_file)


def test_flipped_byte_in_an_array_names_the_array(space_file):
    offset = inspect_container(space_file)["arrays"]["faces"]["offset"]
    raw = read_bytes(space_file)
    raw[offset + 5] ^= 0x10
    space_file.write_bytes(raw)
    with pytest.raises(MotionSpaceError, match="array 'faces' is corrupt") as caught:
        Container.open(space_file)
    assert str(caught.value).startswith(str(space_file))
    with Container.open(space_file, verify=False) as container:  # deferred verification
        container.verify("scalar")
        with pytest.raises(MotionSpaceError, match="'faces'"):
            container.verify()
        with pytest.raises(MotionSpaceError, match="'faces'"):
            container.verify("faces")


@pytest.mark.parametrize("where", ["header_json", "stored_checksum", "header_length_byte"])
def test_flipped_byte_in_the_header_is_an_error(space_file, where):
    raw = read_bytes(space_file)
    index = {"header_json": 36 + 40, "stored_checksum": 25, "header_length_byte": 12}[where]
    raw[index] ^= 0x01
    space_file.write_bytes(raw)
    with pytest.raises(MotionSpaceError, match="header is corrupt|truncated") as caught:
        Container.open(space_file)
    assert str(caught.value).startswith(str(space_file))


def test_every_single_byte_flip_in_the_header_is_caught(tmp_path):
    path = write_container(tmp_path / "s.mspace", {"x": np.arange(4.0)}, {"k": "v"})
    raw = path.read_bytes()
    header_end = 36 + struct.unpack_from("<Q", raw, 12)[0]
    for index in range(header_end):
        damaged = bytearray(raw)
        damaged[index] ^= 0x04
        path.write_bytes(damaged)
        with pytest.raises(MotionSpaceError):
            Container.open(path)


def test_foreign_files_are_not_motion_space_files(tmp_path):
    png = tmp_path / "image.mspace"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    npz = tmp_path / "arrays.npz"
    np.savez(npz, x=np.arange(3))
    npy = tmp_path / "array.npy"
    np.save(npy, np.arange(3))
    empty = tmp_path / "empty.mspace"
    empty.write_bytes(b"")
    text = tmp_path / "text.mspace"
    text.write_text("hello, this is not a motion space at all\n")
    pickled = tmp_path / "pickle.mspace"
    pickled.write_bytes(pickle.dumps({"x": 1}))
    for path in (png, npz, npy, empty, text, pickled):
        with pytest.raises(MotionSpaceError, match="not a motion space file") as caught:
            Container.open(path)
        assert str(caught.value).startswith(str(path)), path
    with pytest.raises(MotionSpaceError, match="PNG"):
        inspect_container(png)
    with pytest.raises(MotionSpaceError, match="zip"):
        inspect_container(npz)
    with pytest.raises(MotionSpaceError, match="empty"):
        inspect_container(empty)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(MotionSpaceError, match="no such file"):
        Container.open(tmp_path / "absent.mspace")
    with pytest.raises(MotionSpaceError, match="directory"):
        Container.open(tmp_path)


def test_future_version_is_refused(space_file):
    raw = read_bytes(space_file)
    struct.pack_into("<I", raw, 8, 2)
    space_file.write_bytes(raw)
    with pytest.raises(MotionSpaceError, match="version 2 is newer") as caught:
        Container.open(space_file)
    assert str(caught.value).startswith(str(space_file))


def rewrite_header(path, edit):
    """Re-sign a file after `edit(header)`: tests header checks behind a valid checksum."""
    import hashlib

    raw = path.read_bytes()
    old_length = struct.unpack_from("<Q", raw, 12)[0]
    header = json.loads(raw[36:36 + old_length])
    edit(header)
    text = json.dumps(header, separators=(",", ":")).encode()
    assert len(text) <= old_length
    text = text.ljust(old_length)  # JSON allows trailing spaces; offsets stay valid
    preamble = raw[:20]
    checksum = hashlib.blake2b(preamble + text, digest_size=16).digest()
    path.write_bytes(preamble + checksum + text + raw[36 + old_length:])


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda h: h.update(format="something-else"), "format"),
        (lambda h: h.update(version=7), "version"),
        (lambda h: h["arrays"]["faces"].update(dtype="|O"), "unsupported dtype"),
        (lambda h: h["arrays"]["faces"].update(dtype="<U1"), "unsupported dtype"),
        (lambda h: h["arrays"]["faces"].update(offset=h["arrays"]["faces"]["offset"] + 4),
         "multiple of 64"),
        (lambda h: h["arrays"]["faces"].update(nbytes=4), "nbytes"),
        (lambda h: h["arrays"]["faces"].update(shape=[-4]), "shape"),
        (lambda h: h["arrays"]["faces"].update(offset=64), "overlaps"),
        (lambda h: h["arrays"]["faces"].pop("checksum"), "checksum"),
        (lambda h: h.update(metadata=[1]), "metadata"),
    ],
)
def test_inconsistent_header_is_malformed(space_file, edit, message):
    rewrite_header(space_file, edit)
    with pytest.raises(MotionSpaceError, match=f"malformed header.*{message}"):
        Container.open(space_file)


def test_rewrite_header_helper_keeps_a_valid_file(space_file):
    rewrite_header(space_file, lambda header: None)
    assert Container.open(space_file)["faces"].sum() == 66


# --------------------------------------------------------------------------------------------
# Refused on write


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (np.array([{"a": 1}, None], dtype=object), "Python objects"),
        (np.array(["walk", "jog"]), "unicode strings"),
        (np.array([b"x"]), "byte strings"),
        (np.zeros(2, dtype=[("x", "<f4"), ("y", "<i4")]), "structured"),
        (np.array(["2024-01-01"], dtype="datetime64[D]"), "datetimes"),
        (np.zeros(2, dtype=np.longdouble), "not portable"),
        ([[1, 2], [3]], "Python objects|inhomogeneous"),
    ],
)
def test_non_numeric_arrays_are_refused(tmp_path, value, message):
    path = tmp_path / "bad.mspace"
    if np.dtype(np.longdouble).itemsize == 8 and message == "not portable":
        pytest.skip("long double is plain float64 on this platform")
    with pytest.raises(MotionSpaceError, match=message) as caught:
        write_container(path, {"ok": np.zeros(3), "bad": value}, {})
    assert str(caught.value).startswith(f"{path}: array 'bad'")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["", "has space", "tab\t", "caf\u00e9", "a:b", "x*", 3, None])
def test_bad_array_names_are_refused(tmp_path, name):
    with pytest.raises(MotionSpaceError, match="name") as caught:
        write_container(tmp_path / "bad.mspace", {name: np.zeros(2)}, {})
    assert str(caught.value).startswith(str(tmp_path / "bad.mspace"))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("metadata", "where"),
    [
        ({"sources": [{"duration": float("nan")}]}, "metadata['sources'][0]['duration'] is nan"),
        ({"epsilon": float("inf")}, "metadata['epsilon'] is inf"),
        ({"epsilon": np.float32("-inf")}, "metadata['epsilon'] is -inf"),
        ({"when": object()}, "metadata['when'] has type object, which is not JSON"),
        ({"rest": np.zeros(3)}, "metadata['rest'] has type ndarray, which is not JSON"),
        ({"ids": {1, 2}}, "metadata['ids'] has type set"),
        ({"params": {1: "speed"}}, "metadata['params'] has key 1"),
        ({"blob": b"bytes"}, "metadata['blob'] has type bytes"),
    ],
)
def test_non_json_metadata_is_refused_naming_the_key(tmp_path, metadata, where):
    with pytest.raises(MotionSpaceError, match=re.escape(where)):
        write_container(tmp_path / "bad.mspace", {"x": np.zeros(2)}, metadata)
    assert list(tmp_path.iterdir()) == []


def test_arrays_in_metadata_get_a_hint(tmp_path):
    with pytest.raises(MotionSpaceError, match="store arrays in `arrays`"):
        write_container(tmp_path / "bad.mspace", {}, {"rest": np.zeros(3)})


def test_self_containing_metadata_is_refused(tmp_path):
    loop = {"a": []}
    loop["a"].append(loop)
    with pytest.raises(MotionSpaceError, match="contains itself"):
        write_container(tmp_path / "bad.mspace", {}, loop)


def test_arrays_and_metadata_must_be_mappings(tmp_path):
    with pytest.raises(MotionSpaceError, match="mapping"):
        write_container(tmp_path / "bad.mspace", [np.zeros(2)], {})
    with pytest.raises(MotionSpaceError, match="metadata must be a dict"):
        write_container(tmp_path / "bad.mspace", {}, ["not", "a", "dict"])


# --------------------------------------------------------------------------------------------
# Nothing is ever unpickled


def test_module_source_never_uses_pickle_or_np_load():
    for path in sorted(PACKAGE_DIR.glob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                modules = [node.module or ""]
            else:
                modules = []
            for module in modules:
                assert module.split(".")[0] not in {"pickle", "cPickle", "dill", "joblib",
                                                    "cloudpickle", "shelve"}, (path, module)
            if isinstance(node, ast.Call):
                for keyword in node.keywords:
                    is_true = isinstance(keyword.value, ast.Constant) and keyword.value.value
                    assert not (keyword.arg == "allow_pickle" and is_true), path


def test_opening_and_reading_never_unpickle(space_file, monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("unpickling attempted")

    monkeypatch.setattr(pickle, "load", forbidden)
    monkeypatch.setattr(pickle, "loads", forbidden)
    monkeypatch.setattr(np, "load", forbidden)
    with Container.open(space_file) as container:
        for name in container:
            container[name].copy()
    inspect_container(space_file)


# --------------------------------------------------------------------------------------------
# Big arrays are mapped, not copied


def resident_bytes():
    """Current resident set size from /proc (Linux), or None."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
    except (OSError, IndexError, ValueError):
        return None
    return pages * os.sysconf("SC_PAGE_SIZE")


def test_a_50_mb_array_is_mapped_not_read(tmp_path):
    rows = 50 * 2**20 // (4 * 3)
    path = write_container(
        tmp_path / "big.mspace", {"V": np.ones((rows, 3), dtype=np.float32)}, {"rows": rows}
    )
    gc.collect()
    before = resident_bytes()
    container = Container.open(path, verify=False)
    V = container["V"]
    assert V.shape == (rows, 3) and V.flags.writeable is False
    assert any(isinstance(obj, mmap.mmap) for obj in walk_bases(V))
    assert V[rows // 2, 1] == 1.0  # touches one page only
    if before is not None:
        assert resident_bytes() - before < 10 * 2**20  # the array itself is 50 MB
    container.verify()  # deferred check reads everything once
    container.close()
    assert V[-1, -1] == 1.0  # still valid after close
    del V
    gc.collect()


def test_npz_written_by_numpy_is_foreign_even_with_mspace_name(tmp_path):
    path = tmp_path / "fake.mspace"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("header.json", "{}")
    with pytest.raises(MotionSpaceError, match="not a motion space file.*zip"):
        Container.open(path)
