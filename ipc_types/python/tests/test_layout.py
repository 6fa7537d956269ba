"""The ctypes mirror against the Rust layout: the compiler's sizes, alignments and field offsets
(``ipc_types/examples/wire_layout.rs`` prints them with ``offset_of!``), the type names and the
constants, compared with :mod:`op3dsg.wire` one by one. No figure here is typed by hand."""

from __future__ import annotations

import ctypes
import json
import subprocess

import pytest

from op3dsg import wire

from conftest import wire_layout_path


@pytest.fixture(scope="module")
def rust():
    out = subprocess.run([str(wire_layout_path())], check=True, capture_output=True, text=True, timeout=60).stdout
    return json.loads(out)


def test_every_rust_wire_type_is_mirrored_and_nothing_else(rust):
    assert sorted(rust["types"]) == sorted(wire.WIRE_TYPES)


@pytest.mark.parametrize("name", sorted(wire.WIRE_TYPES))
def test_size_alignment_type_name_and_every_field_offset_match_rust(rust, name):
    expected = rust["types"][name]
    mirror = wire.WIRE_TYPES[name]
    assert mirror.type_name() == expected["type_name"]
    assert ctypes.sizeof(mirror) == expected["size"], f"{name} size"
    assert ctypes.alignment(mirror) == expected["align"], f"{name} alignment"
    rust_fields = [(f["name"], f["offset"], f["size"]) for f in expected["fields"]]
    py_fields = [(f, getattr(mirror, f).offset, getattr(mirror, f).size) for f in mirror.field_names()]
    assert py_fields == rust_fields, f"{name}: (field, offset, size) in order"


@pytest.mark.parametrize("name,dtype", [("Node", wire.NODE_DTYPE), ("Edge", wire.EDGE_DTYPE)])
def test_numpy_record_dtypes_have_the_rust_offsets_and_record_size(rust, name, dtype):
    expected = rust["types"][name]
    assert dtype.itemsize == expected["size"]
    assert list(dtype.names) == [f["name"] for f in expected["fields"]]
    for field in expected["fields"]:
        sub, offset = dtype.fields[field["name"]][:2]
        assert (offset, sub.itemsize) == (field["offset"], field["size"]), f"{name}.{field['name']}"


def test_constants_match_rust(rust):
    constants = rust["constants"]
    missing = [name for name in constants if not hasattr(wire, name)]
    assert not missing, f"constants of the Rust contract without a Python mirror: {missing}"
    for name, value in constants.items():
        mirrored = getattr(wire, name)
        if isinstance(value, list):
            mirrored = list(mirrored)
        assert mirrored == value, name
