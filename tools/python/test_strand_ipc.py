#!/usr/bin/env python3
"""Checks strand_ipc.py against the Rust wire contract (wire/src/lib.rs), without iceoryx2 or cargo.

Sizes alone do not catch two same-typed fields swapped, so this parses every ``#[repr(C)]`` message
struct of the Rust source and compares field names, scalar types and array lengths in order, the
``#[type_name]`` strings, the enums' values and the constants. Runs under pytest or as a script
(exit 0 when everything matches).
"""

from __future__ import annotations

import ctypes
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import strand_ipc as ipc  # noqa: E402

LIB_RS = os.path.join(HERE, "..", "..", "wire", "src", "lib.rs")

_SCALARS = {"u32": ctypes.c_uint32, "u64": ctypes.c_uint64, "f64": ctypes.c_double, "i32": ctypes.c_int32, "u8": ctypes.c_uint8}


def _source() -> str:
    with open(LIB_RS, encoding="utf-8") as f:
        return f.read()


def _rust_constants(src: str) -> dict[str, int]:
    return {m[1]: int(m[2]) for m in re.finditer(r"pub const (\w+): \w+ = (\d+);", src)}


def _rust_structs(src: str) -> dict[str, tuple[str, list[tuple[str, str]]]]:
    """struct name -> (type_name, [(field, rust type)])."""
    out = {}
    pattern = r'#\[type_name\("([^"]+)"\)\]\s*#\[repr\(C\)\]\s*pub struct (\w+) \{(.*?)\n\}'
    for m in re.finditer(pattern, src, re.S):
        body = re.sub(r"//[^\n]*", "", m[3])
        fields = re.findall(r"pub (\w+): ([^,]+),", body)
        out[m[2]] = (m[1], [(n, t.strip()) for n, t in fields])
    return out


def _rust_enums(src: str) -> dict[str, dict[str, int]]:
    out = {}
    # The wire enums are declared through `wire_enum! { ... pub enum Name { Variant = N, ... } }`.
    for m in re.finditer(r"pub enum (\w+) \{(.*?)\n\s*\}", src, re.S):
        body = re.sub(r"//[^\n]*", "", m[2])
        out[m[1]] = {n: int(v) for n, v in re.findall(r"(\w+) = (\d+),", body)}
    return out


def _rust_flag_mod(src: str, module: str) -> dict[str, int]:
    m = re.search(r"pub mod " + module + r" \{(.*?)\n\}", src, re.S)
    assert m, module
    return {n: int(v) for n, v in re.findall(r"pub const (\w+): u32 = (\d+);", m[1])}


def _snake(name: str) -> str:
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).upper()


def _expected_ctype(rust_type: str, consts: dict[str, int]):
    rust_type = rust_type.replace(" ", "")
    m = re.fullmatch(r"\[(\w+);(\w+)\]", rust_type)
    if m:
        elem = _SCALARS.get(m[1]) or getattr(ipc, m[1])
        n = int(m[2]) if m[2].isdigit() else consts[m[2]]
        return elem, n
    return _SCALARS[rust_type], None


def test_constants():
    consts = _rust_constants(_source())
    assert consts["CONTRACT_VERSION"] == ipc.CONTRACT_VERSION
    assert consts["MAX_JOINTS"] == ipc.MAX_JOINTS
    assert consts["SEGMENT_BATCH_CAPACITY"] == ipc.SEGMENT_BATCH_CAPACITY
    assert 'DEFAULT_PREFIX: &str = "strand/cell"' in _source() and ipc.DEFAULT_PREFIX == "strand/cell"


def test_structs_match_field_by_field():
    src = _source()
    consts = _rust_constants(src)
    structs = _rust_structs(src)
    assert set(structs) == {t.__name__ for t in ipc.MESSAGE_TYPES}, sorted(structs)
    for name, (type_name, fields) in structs.items():
        cls = getattr(ipc, name)
        assert cls.type_name() == type_name, (name, cls.type_name(), type_name)
        py_fields = cls._fields_
        assert [f for f, _ in py_fields] == [f for f, _ in fields], name
        for (fname, ctype), (_, rust_type) in zip(py_fields, fields):
            elem, n = _expected_ctype(rust_type, consts)
            if n is None:
                assert ctype is elem, (name, fname, ctype, rust_type)
            else:
                assert issubclass(ctype, ctypes.Array) and ctype._length_ == n and ctype._type_ is elem, (name, fname)


def test_sizes():
    for cls, size in ipc.EXPECTED_SIZES.items():
        assert ctypes.sizeof(cls) == size, cls
        assert ctypes.alignment(cls) == 8, cls


def test_enums():
    src = _source()
    enums = _rust_enums(src)
    mapping = {
        "SegmentKind": ipc.SegmentKind,
        "Command": ipc.Command,
        "RunState": ipc.RunState,
        "FaultCode": ipc.FaultCode,
        "RejectReason": ipc.RejectReason,
        "JobOutcome": ipc.JobOutcome,
        "LogState": ipc.LogState,
        "Heater": ipc.Heater,
        "HeatWait": ipc.HeatWait,
        "HeatHold": ipc.HeatHold,
    }
    assert set(enums) == set(mapping), sorted(enums)
    for rust_name, py in mapping.items():
        want = {_snake(k): v for k, v in enums[rust_name].items()}
        got = {m.name: m.value for m in py}
        assert got == want, (rust_name, got, want)
    for module, py in (
        ("segment_flags", ipc.SegmentFlags),
        ("extruder_flags", ipc.ExtruderFlags),
        ("joint_state_flags", ipc.JointStateFlags),
        ("heater_flags", ipc.HeaterFlags),
    ):
        want = _rust_flag_mod(src, module)
        got = {m.name: m.value for m in py if m.value}
        assert got == want, (module, got, want)


def test_service_names():
    n = ipc.service_names("strand/test/")
    assert n.segments == "strand/test/segments"
    assert n.status == "strand/test/status"
    src = _source()
    for method in (
        "segments",
        "control",
        "joint_state",
        "base_pose",
        "joint_command",
        "extruder_command",
        "base_command",
        "status",
        "heater_state",
        "heater_command",
    ):
        assert f'format!("{{}}/{method}", self.prefix)' in src, method
        assert getattr(n, method) == f"strand/test/{method}"


if __name__ == "__main__":
    failed = 0
    for name, fn in sorted(globals().items()):
        if name.startswith("test_") and callable(fn):
            try:
                fn()
                print(f"ok   {name}")
            except AssertionError as e:
                failed += 1
                print(f"FAIL {name}: {e}")
    sys.exit(1 if failed else 0)
