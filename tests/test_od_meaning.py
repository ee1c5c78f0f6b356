"""``ecatcfg od``: values beside the dictionary (``--values``) and the ESI comparison by
meaning, on a real vendor ESI: an Elmo drive emulated from its own ESI differs from it in
nothing.

What the ESI says is read here with lxml (ETG.2000 Dictionary: Object, DataType SubItem,
Flags/Access with its Read/WriteRestrictions), not with the package's ESI reader; the
ETG.1000.6 layouts of the communication area are written out in this file.
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import pytest
from lxml import etree
from rig import serve_in_memory, serving

from ecatcfg.esi.library import Library
from ecatcfg.runtime.master import od_tool
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment

ROOT = Path(__file__).resolve().parent.parent
DRIVE_ESI = ROOT / "examples" / "esi" / "ecatcfg-EXD402-drive.xml"
ELMO = Path("esi") / "drives" / "Elmo_ECAT_00010420_V11.xml"
# The Elmo file describes four devices; this one has the full dictionary (216 objects).
ELMO_TYPE = '<Type ProductCode="#x00030924" RevisionNo="#x00010420">'
ELMO_MODES = ("<Index>#x6060</Index>\n\t      <Name>Modes of operation</Name>\n\t      "
              "<Type>SINT</Type>\n\t      <BitSize>8</BitSize>\n\t      <Flags>\n\t\t"
              "<Access>rw</Access>")


def _elmo_device(path: Path):
    lib = Library([path], cache=False)
    entry = next(e for e in lib.entries
                 if (e.product_code, e.revision) == (0x00030924, 0x00010420))
    return lib.device(entry)


def _upload(device, **kwargs):
    link, close = serve_in_memory(segment([SlaveSpec(device, "drive")]))
    try:
        return od_tool.upload_dictionary(Transport(link), 0, **kwargs)
    finally:
        close()


def _elmo_dictionary(text: str) -> etree._Element:
    """The Dictionary element of the device ELMO_TYPE names."""
    root = etree.fromstring(text.encode())
    for device in root.iter("Device"):
        t = device.find("Type")
        if (t.get("ProductCode"), t.get("RevisionNo")) == ("#x00030924", "#x00010420"):
            return device.find("Profile/Dictionary")
    raise AssertionError("no such device")


# ETG.1000.6: the entries of a PDO mapping object are UDINT (index << 16 | sub << 8 |
# bits); the SM communication types of 0x1C00 are USINT.
def _off_standard(dic: etree._Element) -> set[tuple[int, int]]:
    """(index, subindex) of mapping and 0x1C00 entries that the ESI types otherwise."""
    types = {dt.findtext("Name"): dt for dt in dic.find("DataTypes")}
    out = set()
    for obj in dic.find("Objects"):
        index = int(obj.findtext("Index")[2:], 16)
        mapping = 0x1600 <= index < 0x1800 or 0x1A00 <= index < 0x1C00
        if not (mapping or index == 0x1C00):
            continue
        want = "UDINT" if mapping else "USINT"
        for item in types[obj.findtext("Type")].findall("SubItem"):
            if item.find("SubIdx") is not None:
                if int(item.findtext("SubIdx")) > 0 and item.findtext("Type") != want:
                    out.add((index, int(item.findtext("SubIdx"))))
                continue
            arr = types[item.findtext("Type")]
            if arr.findtext("BaseType") != want:
                lbound = int(arr.findtext("ArrayInfo/LBound"))
                out.update((index, lbound + k)
                           for k in range(int(arr.findtext("ArrayInfo/Elements"))))
    return out


def test_an_elmo_drive_emulated_from_its_esi_differs_in_nothing(corpus):
    path = corpus / ELMO
    device = _elmo_device(path)
    objects = _upload(device)
    assert len(objects) > 200
    result = od_tool.compare_with_esi(objects, device)
    assert result.differences == []
    # What the ESI types against ETG.1000.6 (Elmo's 0x1606 lists the mapped objects' types,
    # its 0x1C00 UINTs) is said apart, once per entry, and the slave is not blamed for it.
    off = _off_standard(_elmo_dictionary(path.read_text()))
    assert off, "the Elmo ESI was expected to type some communication entries its own way"
    noted = {(int(n[2:6], 16), int(n[7:9], 16)) for n in result.esi_notes}
    assert noted == off
    assert len(result.esi_notes) == len(off)


def test_one_access_changed_in_the_esi_is_one_difference(corpus, tmp_path):
    text = (corpus / ELMO).read_text()
    head, device_text = text.split(ELMO_TYPE)
    assert ELMO_MODES in device_text
    changed = device_text.replace(ELMO_MODES, ELMO_MODES.replace(">rw<", ">ro<"), 1)
    copy = tmp_path / "elmo-copy.xml"
    copy.write_text(head + ELMO_TYPE + changed)
    objects = _upload(_elmo_device(corpus / ELMO))
    result = od_tool.compare_with_esi(objects, _elmo_device(copy))
    assert result.differences == [
        "0x6060:00 Modes of operation: access rw on the slave, ro in the ESI"]


def test_a_type_of_the_same_size_but_another_meaning_is_a_difference(corpus, tmp_path):
    # DINT and UDINT are 32 bits each, but not the same ETG.1020 type.
    text = (corpus / ELMO).read_text()
    head, device_text = text.split(ELMO_TYPE)
    old = "<Index>#x6064</Index>\n\t      <Name>Position actual value</Name>\n\t      " \
          "<Type>DINT</Type>"
    assert old in device_text
    copy = tmp_path / "elmo-copy.xml"
    copy.write_text(head + ELMO_TYPE + device_text.replace(old, old.replace("DINT", "UDINT"),
                                                           1))
    objects = _upload(_elmo_device(corpus / ELMO))
    result = od_tool.compare_with_esi(objects, _elmo_device(copy))
    assert result.differences == [
        "0x6064:00 Position actual value: type DINT on the slave, UDINT in the ESI"]


def test_pdo_assignment_writable_in_every_state_means_preop(corpus):
    # An ESI's plain rw on a PDO assignment and a slave's "writable in PREOP" say the same:
    # the assignment cannot change after PREOP->SAFEOP.  A mapping written as ro in the
    # ESI and rw on the slave is still a difference.
    from ecatcfg.runtime.mailbox import EntryDescription

    device = _elmo_device(corpus / ELMO)
    objects = _upload(device)
    assign = next(o for o in objects if o.description.index == 0x1C12)
    e = assign.entries[1]
    assert od_tool.access_text(e.access)["write"] == ["PreOp"]
    every = EntryDescription(e.index, e.subindex, e.value_info, e.data_type, e.bit_length,
                             e.access | 0x38, e.name, e.values)
    assign.entries[1] = every
    assert od_tool.compare_with_esi(objects, device).differences == []
    assign.entries[1] = EntryDescription(e.index, e.subindex, e.value_info, e.data_type,
                                         e.bit_length, e.access & ~0x38, e.name, e.values)
    assert od_tool.compare_with_esi(objects, device).differences == [
        f"0x1C12:01 {e.name}: access ro on the slave, rw in the ESI"]


# -- values -----------------------------------------------------------------------------------

def _defaults(path: Path) -> dict[tuple[int, int], bytes]:
    """(index, sub) -> the ESI's DefaultData/DefaultValue of the VAR objects of the example
    drive (hex DefaultData is the wire bytes; DefaultValue a number)."""
    dic = etree.parse(str(path)).find(".//Device/Profile/Dictionary")
    sizes = {"SINT": 1, "INT": 2, "DINT": 4, "USINT": 1, "UINT": 2, "UDINT": 4}
    out = {}
    for obj in dic.find("Objects"):
        t = obj.findtext("Type")
        value = obj.findtext("Info/DefaultValue")
        if t not in sizes or value is None:
            continue
        value = value.strip()
        number = int(value[2:], 16) if value.startswith("#x") else int(value)
        out[(int(obj.findtext("Index")[2:], 16), 0)] = number.to_bytes(
            sizes[t], "little", signed=number < 0)
    return out


@pytest.mark.parametrize("complete_access", [True, False])
def test_values_are_what_the_esi_gives_the_slave(complete_access):
    lib = Library([DRIVE_ESI], cache=False)
    device = lib.device(lib.find("EXD-402").entry)
    objects = {o.description.index: o
               for o in _upload(device, values=True, complete_access=complete_access)}
    defaults = _defaults(DRIVE_ESI)
    assert defaults
    for (index, sub), raw in defaults.items():
        assert objects[index].values[sub] == raw, hex(index)
    # The identity is the device's (ESI Vendor/Id and Type@ProductCode).
    ident = objects[0x1018]
    root = etree.parse(str(DRIVE_ESI))
    vendor = int(root.findtext("Vendor/Id").strip()[2:], 16)
    product = int(root.find(".//Device/Type").get("ProductCode")[2:], 16)
    assert struct.unpack("<B", ident.values[0])[0] == 4
    assert struct.unpack("<I", ident.values[1])[0] == vendor
    assert struct.unpack("<I", ident.values[2])[0] == product
    # Every entry has its value or an abort code, none neither.
    for obj in objects.values():
        for sub in obj.entries:
            assert (sub in obj.values) != (sub in obj.value_aborts), \
                (hex(obj.description.index), sub)
    # Complete access was used where asked (records and arrays read whole).
    assert any(o.complete_access for o in objects.values()) == complete_access


def test_od_values_over_the_wire(veth_netns):
    lib = Library([DRIVE_ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry), "drive")])
    argv = [sys.executable, "-m", "ecatcfg", "od", "--slave", "0", "--values",
            "--iface", veth_netns.if_a]
    with serving(veth_netns, seg):
        text = veth_netns.run_in(veth_netns.ns_a, argv, timeout=120, cwd=ROOT)
        js = veth_netns.run_in(veth_netns.ns_a, argv + ["--format", "json"], timeout=120,
                               cwd=ROOT)
    for done in (text, js):
        assert "Traceback" not in done.stderr and done.returncode == 0, done.stderr
    defaults = _defaults(DRIVE_ESI)
    out = json.loads(js.stdout)
    got = {(o["index"], e["subindex"]): e for o in out["objects"] for e in o["entries"]}
    for (index, sub), raw in defaults.items():
        assert bytes.fromhex(got[(index, sub)]["raw"]) == raw
        assert got[(index, sub)]["value"] == int.from_bytes(
            raw, "little", signed=got[(index, sub)]["type"] in ("SINT", "INT", "DINT"))
    # Text: the value after the entry, as CoE-Online shows it; writes are sdo write's.
    line = next(ln for ln in text.stdout.splitlines() if ln.strip().endswith(
        "Modes of operation = 8") or "Modes of operation = 8 " in ln)
    assert "SINT" in line
    assert "ecatcfg sdo write" in text.stdout


def test_od_esi_of_the_elmo_drive_over_the_wire(veth_netns, corpus, tmp_path):
    # As a user runs it: the device found in the Elmo file (four devices) by the identity
    # in the slave's SII; nothing differs, and in a copy with one access changed, one line.
    path = corpus / ELMO
    text = path.read_text()
    head, device_text = text.split(ELMO_TYPE)
    copy = tmp_path / "elmo-copy.xml"
    copy.write_text(head + ELMO_TYPE + device_text.replace(
        ELMO_MODES, ELMO_MODES.replace(">rw<", ">ro<"), 1))
    seg = segment([SlaveSpec(_elmo_device(path), "drive")])
    argv = [sys.executable, "-m", "ecatcfg", "od", "--slave", "0", "--no-cache",
            "--iface", veth_netns.if_a, "--esi"]
    with serving(veth_netns, seg):
        same = veth_netns.run_in(veth_netns.ns_a, argv + [str(path)], timeout=300, cwd=ROOT)
        other = veth_netns.run_in(veth_netns.ns_a, argv + [str(copy)], timeout=300, cwd=ROOT)
    for done in (same, other):
        assert "Traceback" not in done.stderr, done.stderr
    assert same.returncode == 0, same.stdout[-2000:] + same.stderr
    tail = same.stdout[same.stdout.index("compared with"):].splitlines()
    assert tail[0].endswith(": no differences"), tail[0]
    # The Device element of product 0x00030924, revision 0x00010420 (the file's third).
    line = text[:text.index(ELMO_TYPE)].count("\n")          # the line before its Type
    assert f"{path}:{line} (Elmo Drive)" in tail[0], tail[0]
    assert other.returncode == 1
    tail = other.stdout[other.stdout.index("compared with"):].splitlines()
    assert tail[0].endswith(": 1 difference"), tail[0]
    assert tail[1] == "  0x6060:00 Modes of operation: access rw on the slave, ro in the ESI"
    assert not [ln for ln in tail[2:] if not ln.startswith(("  (more) ", "  (ESI) "))]


@pytest.mark.parametrize("code, later_whole", [(0x06060000, True), (0x06010000, False)])
def test_an_aborted_upload_is_shown_and_complete_access_falls_back(code, later_whole):
    # 0x1018:02 aborts (also the complete access covering it): the identity is read entry
    # by entry, :02 keeps the abort code.  A hardware error leaves complete access to the
    # objects after it; "unsupported access" says the slave takes none, and it is not
    # asked again.
    lib = Library([DRIVE_ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry), "drive")])
    seg.slaves[0].od.inject_abort(0x1018, 2, code)
    link, close = serve_in_memory(seg)
    try:
        objects = od_tool.upload_dictionary(Transport(link), 0, values=True)
    finally:
        close()
    ident = next(o for o in objects if o.description.index == 0x1018)
    assert not ident.complete_access
    assert ident.value_aborts == {2: code} and sorted(ident.values) == [0, 1, 3, 4]
    later = [o for o in objects if o.description.index > 0x1018 and len(o.entries) > 1]
    assert later and all(o.complete_access == later_whole for o in later)
    js = {o["index"]: o for o in od_tool.as_json(objects)}[0x1018]
    assert {e["subindex"]: e.get("abort_code") for e in js["entries"]}[2] == code


def test_complete_access_follows_the_esi_when_one_is_given(veth_netns, tmp_path):
    # The same slave, compared with its ESI and with a copy that says CompleteAccess="false":
    # records read whole with the first, entry by entry with the second.
    text = DRIVE_ESI.read_text()
    assert text.count('CompleteAccess="true"') == 1
    copy = tmp_path / "drive-no-ca.xml"
    copy.write_text(text.replace('CompleteAccess="true"', 'CompleteAccess="false"'))
    lib = Library([DRIVE_ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry), "drive")])
    argv = [sys.executable, "-m", "ecatcfg", "od", "--slave", "0", "--values", "--no-cache",
            "--format", "json", "--iface", veth_netns.if_a, "--esi"]
    with serving(veth_netns, seg):
        whole = veth_netns.run_in(veth_netns.ns_a, argv + [str(DRIVE_ESI)], timeout=120,
                                  cwd=ROOT)
        parts = veth_netns.run_in(veth_netns.ns_a, argv + [str(copy)], timeout=120, cwd=ROOT)
    for done in (whole, parts):
        assert "Traceback" not in done.stderr and done.returncode == 0, done.stderr
    records = [[o["complete_access"] for o in json.loads(d.stdout)["objects"]
                if len(o["entries"]) > 1] for d in (whole, parts)]
    assert records[0] and all(records[0]) and not any(records[1])
    assert [[e["raw"] for o in json.loads(d.stdout)["objects"] for e in o["entries"]]
            for d in (whole, parts)] == [[e["raw"] for o in json.loads(whole.stdout)["objects"]
                                          for e in o["entries"]]] * 2
