"""``pointrig synth`` reads only what belongs to the model and overwrites nothing unasked: a
glTF buffer is read only from a regular file inside the model's folder, within a size limit;
``synth -o DIR`` refuses a non-empty DIR without ``--force``.

The oracle for the accepted case is the same model read from its GLB (one container, no
external file).
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest
from synth_helpers import write_two_bone_glb

from pointrig.cli import main
from pointrig.errors import FormatError, InputError
from pointrig.synth import gltf as gltf_mod
from pointrig.synth.gltf import load_gltf


def _split_glb(glb: Path) -> tuple[dict, bytes]:
    """The JSON document and the binary chunk of a GLB file."""
    raw = glb.read_bytes()
    jlen = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + jlen])
    blen = struct.unpack_from("<I", raw, 20 + jlen)[0]
    return doc, raw[28 + jlen:28 + jlen + blen]


@pytest.fixture
def model(tmp_path: Path) -> tuple[Path, dict, bytes]:
    """``tmp/model/rig.glb`` (the reference) and its document and buffer, with
    ``tmp/secret.bin`` (the same bytes) outside the model's folder."""
    folder = tmp_path / "model"
    folder.mkdir()
    glb = folder / "rig.glb"
    write_two_bone_glb(glb)
    doc, body = _split_glb(glb)
    (tmp_path / "secret.bin").write_bytes(body)
    return glb, doc, body


def _gltf_with_uri(glb: Path, doc: dict, uri: str, byte_length: int | None = None) -> Path:
    doc = json.loads(json.dumps(doc))
    doc["buffers"][0]["uri"] = uri
    if byte_length is not None:
        doc["buffers"][0]["byteLength"] = byte_length
    path = glb.parent / "rig.gltf"
    path.write_text(json.dumps(doc))
    return path


def test_a_buffer_file_in_the_model_folder_is_read(model):
    glb, doc, body = model
    (glb.parent / "rig data.bin").write_bytes(body + b"trailing bytes past the buffer")
    ref = load_gltf(glb)
    got = load_gltf(_gltf_with_uri(glb, doc, "rig%20data.bin"))
    np.testing.assert_array_equal(got.vertices, ref.vertices)
    np.testing.assert_array_equal(got.weights, ref.weights)
    np.testing.assert_array_equal(got.triangles, ref.triangles)


@pytest.mark.parametrize("uri,message", [
    ("../secret.bin", "points outside the model's folder"),
    ("%2E%2E/secret.bin", "points outside the model's folder"),
    ("sub/../../secret.bin", "points outside the model's folder"),
    ("/dev/zero", "is not a relative file name"),
    ("file:///dev/zero", "is not a relative file name"),
    ("https://example.com/rig.bin", "is not a relative file name"),
    ("missing.bin", "not found"),
])
def test_a_buffer_uri_outside_the_model_folder_is_refused(model, uri, message):
    glb, doc, _ = model
    with pytest.raises(InputError, match=message):
        load_gltf(_gltf_with_uri(glb, doc, uri))


def test_links_and_special_files_are_refused(model):
    glb, doc, _ = model
    (glb.parent / "to_secret.bin").symlink_to(glb.parent.parent / "secret.bin")
    with pytest.raises(InputError, match="points outside the model's folder"):
        load_gltf(_gltf_with_uri(glb, doc, "to_secret.bin"))
    (glb.parent / "zero.bin").symlink_to("/dev/zero")
    with pytest.raises(InputError, match="points outside the model's folder"):
        load_gltf(_gltf_with_uri(glb, doc, "zero.bin"))
    os.mkfifo(glb.parent / "pipe.bin")  # reading it would block for ever
    with pytest.raises(InputError, match="is not a regular file"):
        load_gltf(_gltf_with_uri(glb, doc, "pipe.bin"))


def test_buffer_sizes_are_bounded(model, monkeypatch):
    glb, doc, body = model
    (glb.parent / "rig.bin").write_bytes(body)
    with pytest.raises(FormatError, match=f"holds {len(body)} bytes, the buffer declares"):
        load_gltf(_gltf_with_uri(glb, doc, "rig.bin", byte_length=len(body) + 1))
    # a buffer file far larger than the model (the limit lies between the two)
    (glb.parent / "rig.bin").write_bytes(body + bytes(8000))
    gltf = _gltf_with_uri(glb, doc, "rig.bin")
    assert gltf.stat().st_size < 4000
    monkeypatch.setattr(gltf_mod, "MAX_GLTF_BYTES", 4000)
    with pytest.raises(InputError, match=f"holds {len(body) + 8000} bytes, more than the 4000"):
        load_gltf(gltf)


def test_synth_refuses_a_non_empty_folder_without_force(tmp_path, capsys):
    out = tmp_path / "seq"
    args = ["synth", "arm", "--frames", "2", "--resolution", "320", "-o", str(out)]
    assert main(args) == 0
    capsys.readouterr()
    first = sorted(p.name for p in (out / "frames").iterdir())
    (out / "notes.txt").write_text("keep\n")
    stamp = {p: p.read_bytes() for p in (out / "frames").iterdir()}
    assert main(args[:3] + ["3"] + args[4:]) == 1
    err = capsys.readouterr().err.strip()
    assert err == (f"pointrig synth: error: {out}: the output folder is not empty; pass --force "
                   "to replace its frames/ and gt.npz")
    assert {p: p.read_bytes() for p in (out / "frames").iterdir()} == stamp
    assert main(args[:3] + ["3"] + args[4:] + ["--force"]) == 0
    assert sorted(p.name for p in (out / "frames").iterdir()) == first + ["frame_0002.ply"]
    assert (out / "notes.txt").read_text() == "keep\n"
    a_file = tmp_path / "a_file"
    a_file.write_text("x\n")
    assert main(["synth", "arm", "-o", str(a_file)]) == 1
    assert "is a file, not a folder" in capsys.readouterr().err
