"""``ecatcfg od``: the object dictionary an emulated slave describes over SDO Information,
against the ESI it was emulated from, read here with lxml and the ETG.2000 rules written out
in this file (not with the package's ESI reader).

The slave is the example EXD-402 drive; one variant of its ESI has a 34-byte mailbox (the
smallest its SMs allow), so the OD list arrives in fragments and long names are cut to
what one message holds (as SOES answers).  tshark dissects every frame of the run.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from lxml import etree
from rig import serving, tshark_fields, tshark_malformed

from ecatcfg.esi.library import Library
from ecatcfg.runtime import mailbox as mbx
from ecatcfg.runtime.master import od_tool
from ecatcfg.runtime.master.sdo_info import SdoInfoRequest
from ecatcfg.runtime.master.sdo_tool import SdoToolError
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.objects import ObjectDictionary
from ecatcfg.runtime.segment.sdo_info_server import SdoInfoServer

ROOT = Path(__file__).resolve().parent.parent
DRIVE_ESI = ROOT / "examples" / "esi" / "ecatcfg-EXD402-drive.xml"
COUPLER_ESI = ROOT / "examples" / "esi" / "ecatcfg-EX1100-coupler.xml"

# ETG.1000.6 / CiA 301 data type indices of the base types the example dictionary uses.
TYPE_INDEX = {"BOOL": 1, "SINT": 2, "INT": 3, "DINT": 4, "USINT": 5, "UINT": 6, "UDINT": 7}
STATES = ["PreOp", "SafeOp", "Op"]
# The object an emulated slave adds to an ESI dictionary that lacks it (the SM types a
# master reads): the only one on the slave that the example ESI does not describe.
ADDED_BY_THE_EMULATION = {0x1C00}


def small_mailbox_esi(folder: Path, *, sdo_info: bool = True) -> Path:
    """The example drive with 34-byte mailbox SMs (its MinSize), optionally without
    SDO Information."""
    text = DRIVE_ESI.read_text()
    text = text.replace('DefaultSize="128" Enable="1" MaxSize="256" MinSize="34"',
                        'DefaultSize="34" Enable="1" MaxSize="256" MinSize="34"')
    assert text.count('DefaultSize="34"') == 2
    if not sdo_info:
        text = text.replace('SdoInfo="true"', 'SdoInfo="false"')
    path = folder / "drive-small-mailbox.xml"
    path.write_text(text)
    return path


# -- the ESI dictionary, read with lxml ---------------------------------------------------------

def _number(text: str) -> int:
    text = text.strip()
    return int(text[2:], 16) if text.startswith("#x") else int(text)


def _access(flags: etree._Element | None) -> tuple[list[str], list[str]] | None:
    """(read states, write states) of a Flags element (ETG.2000 Access with
    Read/WriteRestrictions such as ``PreOp`` or ``PreOp_SafeOp``)."""
    access = flags.find("Access") if flags is not None else None
    if access is None:
        return None

    def states(restriction: str | None) -> list[str]:
        if not restriction:
            return list(STATES)
        allowed = {part.lower() for part in restriction.split("_")}
        return [s for s in STATES if s.lower() in allowed]

    value = access.text.strip()
    return (states(access.get("ReadRestrictions")) if "r" in value else [],
            states(access.get("WriteRestrictions")) if "w" in value else [])


def esi_dictionary(path: Path) -> dict[int, dict]:
    """index -> {"object": VAR|ARRAY|RECORD, "name", "entries": {sub: (type, bits,
    (read, write))}} for the first device of ``path``."""
    dic = etree.parse(str(path)).find(".//Device/Profile/Dictionary")
    types = {dt.findtext("Name"): dt for dt in dic.find("DataTypes")}
    out: dict[int, dict] = {}
    for obj in dic.find("Objects"):
        index = _number(obj.findtext("Index"))
        type_name = obj.findtext("Type")
        flags = _access(obj.find("Flags"))
        dt = types.get(type_name)
        items = dt.findall("SubItem") if dt is not None else []
        entries: dict[int, tuple] = {}
        if not items:
            kind = "VAR"
            entries[0] = (type_name, _number(obj.findtext("BitSize")), flags)
        else:
            numbered = [i for i in items if i.find("SubIdx") is not None]
            unnumbered = [i for i in items if i.find("SubIdx") is None]
            kind = "ARRAY" if len(numbered) == 1 and len(unnumbered) == 1 else "RECORD"
            for item in numbered:
                entries[_number(item.findtext("SubIdx"))] = (
                    item.findtext("Type"), _number(item.findtext("BitSize")),
                    _access(item.find("Flags")) or flags)
            for item in unnumbered:                  # the array part: ArrayInfo
                arr = types[item.findtext("Type")]
                lbound = _number(arr.findtext("ArrayInfo/LBound"))
                count = _number(arr.findtext("ArrayInfo/Elements"))
                bits = _number(arr.findtext("BitSize")) // count
                for k in range(count):
                    entries[lbound + k] = (arr.findtext("BaseType"), bits,
                                           _access(item.find("Flags")) or flags)
        out[index] = {"object": kind, "name": obj.findtext("Name"), "entries": entries}
    return out


# -- the codec and the server, without a wire -----------------------------------------------------

def test_an_entry_description_with_optional_values_gives_the_name_after_them():
    # index 0x6060:00, value info unit+default+min+max, SINT (0x0002), 8 bits, access 0x3F:
    # unit u16, then default, min, max of 1 byte each, then the name.
    data = (struct.pack("<HBBHHH", 0x6060, 0, 0x78, 0x0002, 8, 0x003F)
            + b"\x00\x00" + b"\x08\xf6\x0a" + b"Modes of operation")
    entry = mbx.EntryDescription.unpack(data)
    assert (entry.index, entry.subindex, entry.data_type, entry.bit_length, entry.access) \
        == (0x6060, 0, 2, 8, 0x3F)
    assert entry.name == "Modes of operation" and entry.values == b"\x00\x00\x08\xf6\x0a"


def test_a_small_mailbox_gets_the_od_list_in_fragments(lib_drive):
    od = ObjectDictionary.from_device(lib_drive)
    server = SdoInfoServer(od, 34)                 # 22 bytes of list per fragment
    client = SdoInfoRequest(mbx.SdoInfoOpcode.OD_LIST_REQUEST, mbx_out_size=34)
    request = mbx.decode(client.first_request())[1]
    replies = server.handle(request)
    headers = [mbx.decode(r)[1] for r in replies]
    n = len(replies)
    expected = sorted(set(esi_dictionary(DRIVE_ESI)) | ADDED_BY_THE_EMULATION)
    assert n == -(-(2 + 2 * len(expected)) // 22) > 1
    assert [(h.incomplete, h.fragments_left) for h in headers] \
        == [(k < n - 1, n - 1 - k) for k in range(n)]
    for reply in replies:
        assert client.on_response(reply) is None
    assert client.done and mbx.decode_od_list(client.result) == (1, expected)


@pytest.fixture(scope="module")
def lib_drive():
    lib = Library([DRIVE_ESI], cache=False)
    return lib.device(lib.find("EXD-402").entry)


def test_a_device_without_sdo_information_answers_an_sdo_information_error(tmp_path):
    from rig import serve_in_memory

    from ecatcfg.runtime.master.transport import Transport

    lib = Library([small_mailbox_esi(tmp_path, sdo_info=False)], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry), "drive")])
    link, close = serve_in_memory(seg)
    try:
        with pytest.raises(SdoToolError, match=r"slave 0: .*0x06010000") as raised:
            od_tool.upload_dictionary(Transport(link), 0)
    finally:
        close()
    assert raised.value.abort_code == 0x06010000


# -- over a veth pair, as a user runs it -----------------------------------------------------------

def test_od_of_an_emulated_slave_equals_its_esi_dictionary(veth_netns, tshark_path, tmp_path):
    esi = small_mailbox_esi(tmp_path)
    lib = Library([COUPLER_ESI, esi], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EX1100").entry), "coupler"),
                   SlaveSpec(lib.device(lib.find("EXD-402").entry), "drive")])
    pcap = tmp_path / "od.pcapng"
    with serving(veth_netns, seg):
        done = veth_netns.run_in(
            veth_netns.ns_a, [sys.executable, "-m", "ecatcfg", "od", "--slave", "1",
                              "--esi", str(esi), "--pcap", str(pcap), "--format", "json",
                              "--iface", veth_netns.if_a], timeout=120, cwd=ROOT)
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    esi_od = esi_dictionary(esi)
    got = {o["index"]: o for o in out["objects"]}
    assert set(got) == set(esi_od) | ADDED_BY_THE_EMULATION
    for index, want in esi_od.items():
        obj = got[index]
        # 34 bytes of mailbox - 12 of headers - 6 of object description: 16 for the name.
        assert (obj["object"], obj["name"]) == (want["object"], want["name"][:16]), \
            hex(index)
        entries = {e["subindex"]: e for e in obj["entries"]}
        assert set(entries) == set(want["entries"]), hex(index)
        assert obj["max_subindex"] == max(want["entries"])
        for sub, (type_name, bits, access) in want["entries"].items():
            e = entries[sub]
            assert (e["type"], e["data_type"], e["bit_length"]) \
                == (type_name, TYPE_INDEX[type_name], bits), (hex(index), sub)
            assert (e["read"], e["write"]) == (list(access[0]), list(access[1])), \
                (hex(index), sub)
    assert out["differences"] == []
    assert out["extras"] == ["0x1C00 Sync manager typ: on the slave, not in the ESI"]

    # Every SDO Information frame dissects; the OD list came in fragments (a 34-byte
    # mailbox carries 22 bytes of service data).
    assert tshark_malformed(pcap) == []
    rows = tshark_fields(pcap, ["ecat_mailbox.coe.sdoinfoopcode",
                                "ecat_mailbox.coe.sdoinfofrag"],
                         display_filter="ecat_mailbox.coe.sdoinfoopcode")
    opcodes = {int(r["ecat_mailbox.coe.sdoinfoopcode"][0], 0) & 0x7F for r in rows}
    assert opcodes == {1, 2, 3, 4, 5, 6}
    assert max(int(r["ecat_mailbox.coe.sdoinfofrag"][0], 0) for r in rows) >= 1


def test_od_names_what_differs_from_another_esi(veth_netns, tmp_path):
    # The slave is the example drive; the ESI given says 0x6060 is an INT writable in
    # PREOP only and describes 0x6061, which the slave has not.
    esi = tmp_path / "drive.xml"
    text = DRIVE_ESI.read_text()
    old = ("<Object><Index>#x6060</Index><Name>Modes of operation</Name><Type>SINT</Type>"
           "<BitSize>8</BitSize>")
    assert old in text
    text = text.replace(old, "<Object><Index>#x6061</Index><Name>Modes display</Name>"
                             "<Type>SINT</Type><BitSize>8</BitSize><Flags><Access>ro</Access>"
                             "</Flags></Object>" + old.replace("SINT", "INT")
                             .replace("<BitSize>8", "<BitSize>16"))
    text = text.replace("<DefaultValue>8</DefaultValue></Info><Flags><Access>rw</Access>",
                        '<DefaultValue>8</DefaultValue></Info><Flags><Access '
                        'WriteRestrictions="PreOp">rw</Access>')
    esi.write_text(text)
    lib = Library([DRIVE_ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EXD-402").entry), "drive")])
    with serving(veth_netns, seg):
        done = veth_netns.run_in(
            veth_netns.ns_a, [sys.executable, "-m", "ecatcfg", "od", "--slave", "0",
                              "--esi", str(esi), "--iface", veth_netns.if_a],
            timeout=120, cwd=ROOT)
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 1, done.stdout + done.stderr
    tail = done.stdout[done.stdout.index("compared with"):].splitlines()
    assert tail[1:] == [
        "  0x6061 Modes display: in the ESI, not on the slave",
        "  0x6060:00 Modes of operation: type SINT on the slave, INT in the ESI",
        "  0x6060:00 Modes of operation: 8 bits on the slave, 16 in the ESI",
        "  0x6060:00 Modes of operation: access rw on the slave, rw(w:PreOp) in the ESI",
        "  (more) 0x1C00 Sync manager type: on the slave, not in the ESI",
    ]
    assert "3 differences" not in tail[0] and "4 differences" in tail[0]


def test_usage_errors_exit_2():
    for argv in (["--slave", "-1"], ["--slave", "0", "--timeout", "0"]):
        done = subprocess.run([sys.executable, "-m", "ecatcfg", "od", "--iface", "lo", *argv],
                              capture_output=True, text=True, cwd=ROOT, timeout=60)
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr


def test_soem_reads_the_same_dictionary(veth_netns, pysoem_module):
    # SOEM (through pysoem) as an independent SDO Information client of the emulated drive:
    # what it reads is what the ESI says (the 128-byte mailbox of the example).
    from test_soem import soem

    lib = Library([COUPLER_ESI, DRIVE_ESI], cache=False)
    seg = segment([SlaveSpec(lib.device(lib.find("EX1100").entry), "coupler"),
                   SlaveSpec(lib.device(lib.find("EXD-402").entry), "drive")])
    with serving(veth_netns, seg):
        report = soem(veth_netns, {"od": 1})
    esi_od = esi_dictionary(DRIVE_ESI)
    got = {o["index"]: o for o in report["od"]}
    assert set(got) == set(esi_od) | ADDED_BY_THE_EMULATION
    codes = {"VAR": 7, "ARRAY": 8, "RECORD": 9}
    for index, want in esi_od.items():
        obj = got[index]
        assert (obj["object_code"], obj["name"]) == (codes[want["object"]], want["name"])
        entries = want["entries"]
        # SOEM reads subindex 0 .. max subindex, one entry description each; pysoem keeps
        # a VAR's on the object.
        if want["object"] == "VAR":
            obj["entries"] = [obj]
        assert len(obj["entries"]) == max(entries) + 1
        for sub, (type_name, bits, (read, write)) in entries.items():
            e = obj["entries"][sub]
            access = sum(1 << k for k, s in enumerate(STATES) if s in read) \
                | sum(1 << (3 + k) for k, s in enumerate(STATES) if s in write)
            assert (e["data_type"], e["bit_length"], e["access"] & 0x3F) \
                == (TYPE_INDEX[type_name], bits, access), (hex(index), sub)
