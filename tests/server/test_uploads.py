"""Dataset uploads against a live server: good zips and multipart, and hostile uploads.

Every refused upload must answer a 4xx naming the problem and leave nothing behind: no
dataset, no staging directory, no file outside the data directory.
"""

from __future__ import annotations

import io
import json
import os
import stat
import struct
import zipfile

import httpx
import pytest
from live_server import LiveServer

TOKEN = "test-token-uploads"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
LIMITS = {"MORPHSPACE_TOKEN": TOKEN, "MORPHSPACE_MAX_UPLOAD_BYTES": str(400_000),
          "MORPHSPACE_MAX_UPLOAD_FILES": "40", "MORPHSPACE_MAX_UNPACKED_BYTES": str(3_000_000)}


def tetra_obj(shift=0.0, extra=""):
    """A tetrahedron as OBJ text (4 vertices, 4 faces)."""
    return (f"v {shift} 0 0\nv {1 + shift} 0 0\nv {shift} 1 0\nv {shift} 0 1\n"
            "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n" + extra)


def zip_bytes(files, *, compression=zipfile.ZIP_DEFLATED):
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression) as archive:
        for name, data in files.items():
            if isinstance(data, zipfile.ZipInfo):
                continue
            archive.writestr(name, data)
    return buffer.getvalue()


def good_files(prefix=""):
    files = {f"{prefix}walk/frame_{k}.obj": tetra_obj(0.01 * k) for k in (1, 2, 10)}
    files[f"{prefix}walk/meta.json"] = json.dumps({"fps": 25, "cyclic": True, "note": "kept"})
    files.update({f"{prefix}jump/frame_{k:02d}.obj": tetra_obj(0.02 * k) for k in range(3)})
    return files


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    with LiveServer(tmp_path_factory.mktemp("uploads-data"), env=LIMITS) as server:
        yield server


@pytest.fixture()
def client(live):
    with httpx.Client(base_url=live.url, timeout=30.0) as c:
        yield c


def datasets_state(live):
    """Everything under datasets/ (hidden staging included) and next to the data directory."""
    root = live.data_dir / "datasets"
    return sorted(p.name for p in root.iterdir()), sorted(p.name for p in live.data_dir.parent.iterdir())


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def post_zip(client, name, data, **params):
    return client.post("/v1/datasets", params={"name": name, **params}, content=data,
                       headers={**AUTH, "Content-Type": "application/zip"})


# --- accepted ----------------------------------------------------------------------------------------
def test_zip_upload_becomes_a_dataset(client, live):
    r = post_zip(client, "zipped", zip_bytes(good_files("capture/")))  # one wrapping folder is stripped
    assert r.status_code == 201, r.text
    assert r.headers["location"] == "/v1/datasets/zipped"
    info = r.json()
    seqs = {s["name"]: s for s in info["sequences"]}
    assert set(seqs) == {"walk", "jump"}
    assert seqs["walk"]["frames"] == 3 and seqs["walk"]["fps"] == 25 and seqs["walk"]["cyclic"] is True
    assert seqs["jump"]["fps"] == 30 and seqs["jump"]["cyclic"] is False  # request defaults
    assert seqs["walk"]["vertices"] == 4 and info["buildable"] == ["jump", "walk"]
    root = live.data_dir / "datasets" / "zipped"
    frames = sorted(p.name for p in (root / "sequences" / "walk" / "consistent").iterdir())
    assert frames == ["frame_1.obj", "frame_10.obj", "frame_2.obj"]
    meta = json.loads((root / "sequences" / "walk" / "meta.json").read_text())
    assert meta["name"] == "walk" and meta["note"] == "kept" and meta["topology"] == "consistent"
    assert json.loads((root / "manifest.json").read_text())["format"] == "morphspace-capture-dataset"
    for path in (root / "manifest.json", root / "sequences" / "walk" / "meta.json"):  # as umask gives any new file
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~_umask(), path
    listed = client.get("/v1/datasets").json()
    assert "zipped" in [d["name"] for d in listed["datasets"]]
    assert client.get("/v1/datasets/zipped").json()["frames"] == 6


def test_the_dataset_reads_with_the_engine(live, client):
    from engine.mesh_io import read_sequence

    post_zip(client, "engine-read", zip_bytes(good_files()))
    sequence = read_sequence(live.data_dir / "datasets" / "engine-read" / "sequences" / "walk" / "consistent")
    assert sequence.vertices.shape == (3, 4, 3)
    assert sequence.vertices[2, 0, 0] == pytest.approx(0.10)  # natural order: frame_10 last


def textured_tetra(name, colour=(40, 120, 200), folder=""):
    """A tetrahedron OBJ with a material library and a uniform PNG texture (files by name)."""
    from PIL import Image

    png = io.BytesIO()
    Image.new("RGB", (8, 8), colour).save(png, format="PNG")
    obj = (f"mtllib {name}.mtl\n" + tetra_obj().replace("f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n", "")
           + "vt 0.5 0.5\nusemtl skin\nf 1/1 3/1 2/1\nf 1/1 2/1 4/1\nf 1/1 4/1 3/1\nf 2/1 3/1 4/1\n")
    return {f"{name}.obj": obj, f"{name}.mtl": f"newmtl skin\nmap_Kd {folder}{name}.png\n",
            f"{folder}{name}.png": png.getvalue()}


def test_textured_frames_keep_their_textures(client, live):
    from engine.mesh_io import read_frames

    files = {}
    for k in range(2):
        files.update({f"take/{n}": d for n, d in textured_tetra(f"frame_{k}", folder="maps/").items()})
    files["take/maps/unused.png"] = files["take/maps/frame_0.png"]
    r = post_zip(client, "textured", zip_bytes(files))
    assert r.status_code == 201, r.text
    folder = live.data_dir / "datasets" / "textured" / "sequences" / "take" / "consistent"
    kept = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())
    assert kept == ["frame_0.mtl", "frame_0.obj", "frame_1.mtl", "frame_1.obj", "maps/frame_0.png",
                    "maps/frame_1.png"]   # what no frame refers to is not kept
    frames = read_frames(folder)
    assert frames[1].colors is not None
    assert abs(frames[1].colors[0] - [40 / 255, 120 / 255, 200 / 255]).max() < 1e-6


TEXTURE_REFUSED = {
    "missing texture": ({k: v for k, v in textured_tetra("f").items() if not k.endswith(".png")},
                        "walk/f.obj: refers to 'f.png', which cannot be read beside it"),
    "outside the frame's folder": ({**{k: v for k, v in textured_tetra("f", folder="../").items()
                                       if not k.endswith(".png")}, "f.png": textured_tetra("f")["f.png"]},
                                   "walk/f.obj: refers to '../f.png', outside the frame's folder"),
}


@pytest.mark.parametrize("case", list(TEXTURE_REFUSED))
def test_textured_frame_problems_are_named(client, live, case):
    files, words = TEXTURE_REFUSED[case]
    before = datasets_state(live)
    r = post_zip(client, "badtexture", zip_bytes({(n if n == "f.png" else f"walk/{n}"): d for n, d in files.items()}))
    assert r.status_code == 422, r.text
    assert words in r.json()["detail"]
    assert ".upload-" not in r.json()["detail"] and str(live.data_dir) not in r.json()["detail"]  # no server paths
    assert datasets_state(live) == before


def test_multipart_upload_with_paths_and_unstructured_frames(client):
    files = [("files", ("run/f1.obj", tetra_obj(), "text/plain")),
             ("files", ("run/f2.obj", tetra_obj(0.1, "v 5 5 5\nf 1 2 5\n"), "text/plain")),  # a different mesh
             ("files", ("run/.DS_Store", b"junk", "application/octet-stream"))]  # hidden: skipped
    r = client.post("/v1/datasets", params={"name": "multi", "fps": 12}, files=files, headers=AUTH)
    assert r.status_code == 201, r.text
    (seq,) = r.json()["sequences"]
    assert seq["name"] == "run" and seq["unstructured_frames"] == 2 and seq["consistent_frames"] == 0
    assert seq["fps"] == 12 and r.json()["buildable"] == []


def test_duplicate_name_replace_and_delete(client, live):
    assert post_zip(client, "dup", zip_bytes(good_files())).status_code == 201
    r = post_zip(client, "dup", zip_bytes(good_files()))
    assert r.status_code == 409 and "already exists" in r.json()["detail"]
    r = post_zip(client, "dup", zip_bytes({"only/a.obj": tetra_obj()}), replace="true")
    assert r.status_code == 201 and [s["name"] for s in r.json()["sequences"]] == ["only"]
    assert client.delete("/v1/datasets/dup").status_code == 401
    assert client.delete("/v1/datasets/dup", headers=AUTH).status_code == 204
    assert client.get("/v1/datasets/dup").status_code == 404
    assert not (live.data_dir / "datasets" / "dup").exists()
    assert client.delete("/v1/datasets/dup", headers=AUTH).status_code == 404


def test_a_linked_dataset_is_listed_and_deleting_it_keeps_what_it_links(client, live, tmp_path):
    """scripts/demo publishes its captures as links in datasets/: they are datasets like any other,
    and deleting one removes the link only."""
    assert post_zip(client, "to_link", zip_bytes(good_files())).status_code == 201
    elsewhere = tmp_path / "captures"
    (live.data_dir / "datasets" / "to_link").rename(elsewhere)
    (live.data_dir / "datasets" / "linked").symlink_to(elsewhere, target_is_directory=True)
    listed = {d["name"]: d for d in client.get("/v1/datasets").json()["datasets"]}
    assert "to_link" not in listed and sorted(listed["linked"]["buildable"]) == ["jump", "walk"]
    assert client.delete("/v1/datasets/linked", headers=AUTH).status_code == 204
    assert not (live.data_dir / "datasets" / "linked").exists() and (elsewhere / "manifest.json").is_file()
    assert not [p for p in (live.data_dir / "datasets").iterdir() if p.name.startswith(".")]


def test_token_is_required_to_upload(client, live):
    before = datasets_state(live)
    data = zip_bytes(good_files())
    r = client.post("/v1/datasets", params={"name": "noauth"}, content=data,
                    headers={"Content-Type": "application/zip"})
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
    r = client.post("/v1/datasets", params={"name": "noauth"}, content=data,
                    headers={"Content-Type": "application/zip", "Authorization": "Bearer wrong"})
    assert r.status_code == 401
    assert datasets_state(live) == before
    assert client.get("/v1/datasets").status_code == 200  # reading needs no token


# --- refused ---------------------------------------------------------------------------------------------
def symlink_zip():
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("walk/frame_0.obj", tetra_obj())
        link = zipfile.ZipInfo("walk/frame_1.obj")
        link.external_attr = (stat.S_IFLNK | 0o777) << 16
        archive.writestr(link, "/etc/passwd")
    return buffer.getvalue()


def lying_zip():
    """A member whose headers declare 1,000 bytes but whose data inflates to 2 MB."""
    data = bytearray(zip_bytes({"walk/frame_0.obj": b"v 0 0 0\n" * 262144}))
    real = struct.pack("<I", 262144 * 8)
    fake = struct.pack("<I", 1000)
    assert data.count(real) == 2  # local header and central directory
    return bytes(data.replace(real, fake))


HOSTILE = {
    "zip slip": (lambda: zip_bytes({"walk/a.obj": tetra_obj(), "../escaped.obj": tetra_obj()}), 400, "'..'"),
    "zip slip deep": (lambda: zip_bytes({"walk/../../escaped.obj": tetra_obj()}), 400, "'..'"),
    "absolute path": (lambda: zip_bytes({"/tmp/escaped.obj": tetra_obj()}), 400, "absolute"),
    "symlink": (symlink_zip, 400, "symbolic link"),
    "zip bomb ratio": (lambda: zip_bytes({"walk/frame_0.obj": b"\0" * (4 << 20)}), 413, "compression ratio"),
    "zip bomb lying sizes": (lying_zip, 400, "frame_0.obj"),
    "unpacked size": (lambda: zip_bytes({f"walk/f{k}.obj": tetra_obj() + "# " + "abcdefghij" * 80_000 + "\n"
                                         for k in range(4)}), 413, "MORPHSPACE_MAX_UNPACKED_BYTES"),
    "too many files": (lambda: zip_bytes({f"walk/f{k}.obj": tetra_obj() for k in range(41)}), 413,
                       "MORPHSPACE_MAX_UPLOAD_FILES"),
    "oversize body": (lambda: zip_bytes({"walk/f.obj": bytes(range(256)) * 2000}, compression=zipfile.ZIP_STORED),
                      413, "MORPHSPACE_MAX_UPLOAD_BYTES"),
    "not a zip": (lambda: b"this is not an archive at all", 400, "not a zip"),
    "truncated zip": (lambda: zip_bytes(good_files())[:700], 400, "zip"),
    "corrupt mesh": (lambda: zip_bytes({"walk/frame_0.obj": tetra_obj(), "walk/frame_1.obj": "v 0 0 0\nf 1 2 3\n"}),
                     422, "walk/frame_1.obj"),
    "non-finite vertex": (lambda: zip_bytes({"walk/frame_0.obj": tetra_obj().replace("v 0.0 0 0", "v nan 0 0")}),
                          422, "walk/frame_0.obj"),
    "unsupported file": (lambda: zip_bytes({"walk/frame_0.obj": tetra_obj(), "walk/run.sh": "rm -rf /"}), 422,
                         "walk/run.sh"),
    "bad meta": (lambda: zip_bytes({"walk/frame_0.obj": tetra_obj(), "walk/meta.json": '{"fps": -1}'}), 422,
                 "walk/meta.json"),
    "no frames": (lambda: zip_bytes({"walk/meta.json": "{}"}), 422, "no frames"),
    "meta units": (lambda: zip_bytes({"walk/frame_0.obj": tetra_obj(), "walk/meta.json": '{"units": "furlongs"}'}),
                   422, "units must be one of m, cm, mm, got 'furlongs'"),
    "meta up": (lambda: zip_bytes({"walk/frame_0.obj": tetra_obj(), "walk/meta.json": '{"up": "-X"}'}),
                422, "up must be +Y or +Z"),
    "frame counts differ": (lambda: zip_bytes({**{f"walk/consistent/frame_{k}.obj": tetra_obj() for k in range(3)},
                                               **{f"walk/unstructured/frame_{k}.obj": tetra_obj() for k in range(2)}}),
                            422, "consistent/ has 3 frames and unstructured/ 2"),
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_hostile_zip_is_refused_and_leaves_nothing(client, live, case):
    make, status, words = HOSTILE[case]
    before = datasets_state(live)
    r = post_zip(client, "hostile", make())
    assert r.status_code == status, (case, r.text)
    assert words in r.json()["detail"], (case, r.json())
    assert datasets_state(live) == before
    assert not (live.data_dir.parent / "escaped.obj").exists()
    assert client.get("/v1/datasets/hostile").status_code == 404


def test_chunked_oversize_body_is_cut_off(client, live):
    before = datasets_state(live)

    def body():
        for _ in range(40):
            yield b"PK\x03\x04" + b"x" * 20_000

    r = client.post("/v1/datasets", params={"name": "chunked"}, content=body(),
                    headers={**AUTH, "Content-Type": "application/zip"})
    assert r.status_code == 413 and "MORPHSPACE_MAX_UPLOAD_BYTES" in r.json()["detail"]
    assert datasets_state(live) == before


def test_hostile_multipart_names(client, live):
    before = datasets_state(live)
    for filename, status in (("../escaped.obj", 400), ("/etc/escaped.obj", 400), ("a\\b.obj", 400),
                             ("walk/frame 0;rm.obj", 422)):
        r = client.post("/v1/datasets", params={"name": "badpart"}, headers=AUTH,
                        files=[("files", (filename, tetra_obj(), "text/plain"))])
        assert r.status_code == status, (filename, r.text)
        assert filename in r.json()["detail"], (filename, r.text)
    r = client.post("/v1/datasets", params={"name": "badpart"}, headers=AUTH, data={"field": "value"},
                    files=[("files", ("walk/a.obj", tetra_obj(), "text/plain"))])
    assert r.status_code == 400 and "not a file" in r.json()["detail"]
    assert datasets_state(live) == before


def test_bad_names_and_content_types(client):
    r = post_zip(client, "../up", zip_bytes(good_files()))
    assert r.status_code == 422
    r = client.post("/v1/datasets", params={"name": "textual"}, content=b"hello",
                    headers={**AUTH, "Content-Type": "text/plain"})
    assert r.status_code == 415 and "Content-Type" in r.json()["detail"]
    assert client.get("/v1/datasets/..%2Fspaces").status_code == 404


def test_a_multipart_body_cut_short_is_refused_even_at_a_line_end(client, live):
    """A body without its closing boundary (a client or proxy that stopped sending) is 400: its
    last part may be cut anywhere, and a cut at a line's end still parses as a smaller mesh."""
    before = datasets_state(live)
    whole = tetra_obj(0.0, "".join(f"v {k} 1 1\nf 1 2 {5 + k}\n" for k in range(40)))
    cut = whole[:whole.index("f 1 2 25")]   # at a line's end, inside the faces
    parts = [("walk/frame_0.obj", tetra_obj()), ("walk/frame_1.obj", cut)]
    body = b"".join(b"--XYZ\r\nContent-Disposition: form-data; name=\"files\"; filename=\"" + name.encode()
                    + b"\"\r\nContent-Type: text/plain\r\n\r\n" + text.encode() + b"\r\n" for name, text in parts)
    body = body[:-2]   # no closing --XYZ--: the body ends inside the last part
    r = client.post("/v1/datasets", params={"name": "cutshort"}, content=body,
                    headers={**AUTH, "Content-Type": "multipart/form-data; boundary=XYZ"})
    assert r.status_code == 400, r.text
    assert "closing boundary" in r.json()["detail"] and "walk/frame_1.obj" in r.json()["detail"]
    assert datasets_state(live) == before
    # the same parts with their closing boundary are a dataset
    r = client.post("/v1/datasets", params={"name": "cutshort"}, content=body + b"\r\n--XYZ--\r\n",
                    headers={**AUTH, "Content-Type": "multipart/form-data; boundary=XYZ"})
    assert r.status_code == 201, r.text
    assert client.delete("/v1/datasets/cutshort", headers=AUTH).status_code == 204


def test_staging_of_a_server_that_died_is_removed_at_the_next_start(tmp_path):
    """An upload interrupted by a crash (kill -9) leaves its staging directory; the next start
    removes it at once, however young, and keeps the staging of a process still running."""
    import subprocess
    import sys

    datasets = tmp_path / "data" / "datasets"
    datasets.mkdir(parents=True)
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead = datasets / f".upload-{int(gone.stdout)}-0123456789ab"
    running = datasets / f".upload-{os.getpid()}-ba9876543210"
    old_style = datasets / ".upload-0123456789ab"
    for staging in (dead, running, old_style):
        staging.mkdir()
        (staging / "body").write_bytes(b"PK" + bytes(1000))
    with LiveServer(tmp_path / "data", env=LIMITS) as server:
        assert httpx.get(server.url + "/v1/datasets", timeout=10).status_code == 200
        assert not dead.exists() and not old_style.exists()
        assert running.exists()


def test_a_client_that_disconnects_mid_upload_leaves_nothing_and_no_traceback(live):
    """The client goes away after 100 KB of a 300 KB body: the staging is removed, and the server
    log gets no 'Exception in ASGI application' traceback for it."""
    import socket
    import time

    before = datasets_state(live)
    log_before = live.log.read_text(errors="replace")
    host, port = live.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=10) as conn:
        conn.sendall((f"POST /v1/datasets?name=gone HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer {TOKEN}\r\n"
                      "Content-Type: application/zip\r\nContent-Length: 300000\r\n\r\n").encode() + bytes(100_000))
        time.sleep(0.5)
    for _ in range(100):   # the server notices the disconnect and cleans up
        if not list((live.data_dir / "datasets").glob(".upload-*")):
            break
        time.sleep(0.1)
    assert not list((live.data_dir / "datasets").glob(".upload-*"))
    assert datasets_state(live) == before
    time.sleep(0.3)
    new = live.log.read_text(errors="replace")[len(log_before):]
    assert "Traceback" not in new and "Exception in ASGI" not in new, new


def test_request_bodies_other_than_uploads_are_bounded(tmp_path):
    """A JSON body over MORPHSPACE_MAX_JSON_BYTES is 413 naming it, declared or chunked, before the
    application parses it; uploads keep their own limit (found by a docs-only user: a 20 MB job
    request was parsed whole)."""
    env = {**LIMITS, "MORPHSPACE_MAX_JSON_BYTES": "4096"}
    with LiveServer(tmp_path / "data", env=env) as server, httpx.Client(base_url=server.url, timeout=30) as client:
        big = {"kind": "build", "dataset": "x", "space": "y", "spec": {"sources": ["a" * 5000, "b"]}}
        r = client.post("/v1/jobs", json=big, headers=AUTH)
        assert r.status_code == 413 and "the limit is 4096 bytes (MORPHSPACE_MAX_JSON_BYTES)" in r.json()["detail"]

        def chunks():
            for _ in range(10):
                yield b" " * 1000
        r = client.post("/v1/jobs", content=chunks(), headers={**AUTH, "Content-Type": "application/json"})
        assert r.status_code == 413 and "at least" in r.json()["detail"]
        small = {"kind": "build", "dataset": "x", "space": "y", "spec": {"sources": ["a", "b"]}}
        r = client.post("/v1/jobs", json=small, headers=AUTH)
        assert r.status_code == 404 and "no dataset 'x'" in r.text   # reached the application
        files = {f"walk/frame_{k:02d}.obj": tetra_obj(0.01 * k) for k in range(30)}
        data = zip_bytes(files, compression=zipfile.ZIP_STORED)
        assert len(data) > 4096
        r = post_zip(client, "bigger", data)
        assert r.status_code == 201, r.text
        assert client.get("/v1/health").status_code == 200
