"""``ecatcfg show``: an ESI device and an ENI's network, text and JSON, checked against the
files read here with plain lxml (our ESI and ENI readers are the code under test)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from lxml import etree

from conftest import write
from ecatcfg.cli import main

ELMO_ESI = "esi/drives/Elmo_ECAT_00010420_V11.xml"
SM_NAMES = {"MBoxOut": "mbox out", "MBoxIn": "mbox in", "Outputs": "outputs",
            "Inputs": "inputs"}


def _num(text: str) -> int:
    """ESI/ENI numbers: decimal or ``#x`` hex."""
    text = text.strip()
    return int(text[2:], 16) if text.lower().startswith("#x") else int(text)


def _elmo(corpus: Path) -> etree._Element:
    tree = etree.parse(str(corpus / ELMO_ESI))
    return next(d for d in tree.iter("Device")
                if _num(d.find("Type").get("ProductCode")) == 0x30924
                and _num(d.find("Type").get("RevisionNo")) == 0x10420)


def _json(capsys, *argv: str) -> dict:
    assert main(["show", *argv, "--format", "json", "--no-cache"]) == 0
    return json.loads(capsys.readouterr().out)


def test_show_esi_device_json(corpus, capsys):
    dev = _elmo(corpus)
    shown = _json(capsys, str(corpus / ELMO_ESI), "--device", "0x9a:0x30924:0x10420")
    assert (shown["vendor_id"], shown["product_code"], shown["revision"]) == \
        (0x9A, 0x30924, 0x10420)
    assert shown["type"] == dev.findtext("Type").strip()
    assert shown["mailbox"]["protocols"] == [
        c.tag for c in dev.find("Mailbox") if c.tag in ("AoE", "EoE", "CoE", "FoE", "SoE",
                                                        "VoE")]
    assert [(s["type"], s["start"], s["default_size"], s["control"])
            for s in shown["sms"]] == [
        (sm.text, _num(sm.get("StartAddress")),
         _num(sm.get("DefaultSize")) if sm.get("DefaultSize") else None,
         _num(sm.get("ControlByte"))) for sm in dev.findall("Sm")]
    for key, tag in (("rx_pdos", "RxPdo"), ("tx_pdos", "TxPdo")):
        pdos = dev.findall(tag)
        assert len(shown[key]) == len(pdos) > 20
        for p, el in zip(shown[key], pdos):
            assert p["index"] == _num(el.findtext("Index"))
            assert p["name"] == el.findtext("Name")
            assert p["fixed"] == (el.get("Fixed") in ("1", "true"))
            assert p["mandatory"] == (el.get("Mandatory") in ("1", "true"))
            assert p["default"] == (el.get("Sm") is not None)
            assert p["excludes"] == [_num(x.text) for x in el.findall("Exclude")]
            assert [(e["entry"], e["bit_len"], e["type"], e["name"]) for e in p["entries"]] \
                == [(f"0x{_num(e.findtext('Index')):04X}:{_num(e.findtext('SubIndex')):02X}"
                     if _num(e.findtext("Index")) else None, _num(e.findtext("BitLen")),
                     e.findtext("DataType"), (e.findtext("Name") or "").strip())
                    for e in el.findall("Entry")]
    assert [(m["name"], m["assign_activate"]) for m in shown["dc_opmodes"]] == [
        (m.findtext("Name"), _num(m.findtext("AssignActivate")))
        for m in dev.findall("Dc/OpMode")]
    assert "objects" not in shown


def test_show_esi_objects_with_access_per_state(corpus, capsys):
    dev = _elmo(corpus)
    shown = _json(capsys, str(corpus / ELMO_ESI), "--device", "0x9a:0x30924:0x10420",
                  "--objects")
    objects = {o["index"]: o for o in shown["objects"]}
    xml = {_num(o.findtext("Index")): o for o in dev.iter("Object")}
    assert set(objects) == set(xml)
    # A simple object: its Flags/Access in every state, and its PdoMapping flag.
    checked = 0
    for index, el in xml.items():
        access = el.findtext("Flags/Access")
        if access is None or el.find("SubItem") is not None or el.find("Flags/Access")\
                .get("WriteRestrictions") is not None:
            continue
        entry = objects[index]["entries"][0]
        assert entry["access"] == {s: access for s in ("PreOp", "SafeOp", "Op")}, hex(index)
        assert entry["pdo_mapping"] == el.findtext("Flags/PdoMapping")
        checked += 1
    assert checked > 20


def test_show_esi_text(corpus, capsys):
    assert main(["show", str(corpus / ELMO_ESI), "--device", "0x9a:0x30924:0x10420",
                 "--no-cache"]) == 0
    out = capsys.readouterr().out
    dev = _elmo(corpus)
    first = dev.find("RxPdo")
    assert f"0x{_num(first.findtext('Index')):04X} {first.findtext('Name')!r}" in out
    assert "\x1b[" not in out                       # plain in a pipe
    for m in dev.findall("Dc/OpMode"):
        assert m.findtext("Name") in out


@pytest.mark.parametrize("eni", ["eni/jn-ec-master/mega_master_eni.xml",
                                 "eni/rocos-ethercat/eni.xml",
                                 "eni/acontis-doc/acontis-TrainingSlaves-ENI.xml"])
def test_show_eni_json(corpus, capsys, eni):
    tree = etree.parse(str(corpus / eni))
    shown = _json(capsys, str(corpus / eni))
    slaves = tree.findall("Config/Slave")
    assert [(s["name"], s["phys_addr"], s["position"], s["vendor_id"], s["product_code"],
             s["revision"]) for s in shown["slaves"]] == [
        (s.findtext("Info/Name"), _num(s.findtext("Info/PhysAddr")),
         -_num(s.findtext("Info/AutoIncAddr")) & 0xFFFF, _num(s.findtext("Info/VendorId")),
         _num(s.findtext("Info/ProductCode")), _num(s.findtext("Info/RevisionNo")))
        for s in slaves]
    # The process image: every variable at byte.bit of its BitOffs, size and type.
    image = shown["process_image"]
    xml_vars = [("in" if v.getparent().tag == "Inputs" else "out", v.findtext("Name"),
                 f"{_num(v.findtext('BitOffs')) // 8}.{_num(v.findtext('BitOffs')) % 8}",
                 _num(v.findtext("BitSize")), v.findtext("DataType"))
                for v in tree.findall("Config/ProcessImage/*/Variable")]
    assert [(v["direction"], v["name"], v["offset"], v["bit_size"], v["type"])
            for v in image["variables"]] == xml_vars
    # Frames: each command with its expected working counter.
    assert [[(c["length"], c["wkc"]) for c in f["commands"]] for f in shown["frames"]] == [
        [(_num(c.findtext("DataLength")), _num(c.findtext("Cnt")) if c.find("Cnt")
          is not None else None) for c in f.findall("Cmd")]
        for f in tree.findall("Config/Cyclic/Frame")]
    counted_master: dict[str, int] = {}
    for ic in tree.findall("Config/Master/InitCmds/InitCmd"):
        for t in ic.findall("Transition"):
            counted_master[t.text] = counted_master.get(t.text, 0) + 1
    assert {t: len(w) for t, w in shown["master_init_cmds"].items()} == counted_master
    # InitCmds per transition: one line per register command and transition, then the
    # CoE ones, each SDO download as "SDO 0xIIII:SS = value" from the file's bytes.
    for s, el in zip(shown["slaves"], slaves):
        counted: dict[str, int] = {}
        for ic in el.findall("InitCmds/InitCmd") + el.findall("Mailbox/CoE/InitCmds/InitCmd"):
            for t in ic.findall("Transition"):
                counted[t.text] = counted.get(t.text, 0) + 1
        assert {t: len(w) for t, w in s["init_cmds"].items()} == counted
        for ic in el.findall("Mailbox/CoE/InitCmds/InitCmd"):
            if ic.get("CompleteAccess") in ("1", "true"):
                continue
            data = bytes.fromhex(ic.findtext("Data"))
            index, sub = _num(ic.findtext("Index")), _num(ic.findtext("SubIndex"))
            words = f"SDO 0x{index:04X}:{sub:02X} = "
            t = ic.findtext("Transition")
            assert any(w.startswith(words) for w in s["init_cmds"][t]), (words, t)
            if len(data) == 1:
                assert words + str(data[0]) in s["init_cmds"][t]


def test_show_eni_decodes_syncmanager_writes(corpus, capsys):
    """Each SyncManager write of process data in words, decoded here from the register
    layout (ESC: start 2 bytes, length 2, control 1, status 1, activate 1, PDI 1)."""
    eni = "eni/rocos-ethercat/eni.xml"
    tree = etree.parse(str(corpus / eni))
    shown = _json(capsys, str(corpus / eni))
    found = 0
    for s, el in zip(shown["slaves"], tree.findall("Config/Slave")):
        for ic in el.findall("InitCmds/InitCmd"):
            ado = _num(ic.findtext("Ado"))
            data = bytes.fromhex(ic.findtext("Data") or "")
            if not (0x0810 <= ado < 0x0900 and len(data) == 8 and any(data)):
                continue
            start, length = int.from_bytes(data[0:2], "little"), int.from_bytes(data[2:4],
                                                                                 "little")
            kind = "outputs" if data[4] & 0x0C == 0x04 else "inputs"
            words = (f"set sm {(ado - 0x800) // 8} ({kind}) 0x{start:04X} len {length} "
                     f"ctrl 0x{data[4]:02X}")
            assert words in s["init_cmds"][ic.findtext("Transition")]
            found += 1
    assert found == 2          # SM2 outputs, SM3 inputs
    assert "set sm 2 (outputs) 0x1100 len 14 ctrl 0x64" in shown["slaves"][0]["init_cmds"]["PS"]


def test_show_eni_decodes_fmmu_writes(corpus, capsys):
    """Each FMMU write in words, decoded here from the 16-byte layout (ESC: logical start
    4 bytes, length 2, start bit, stop bit, physical start 2, physical bit, type)."""
    eni = "eni/jn-ec-master/mega_master_eni.xml"
    tree = etree.parse(str(corpus / eni))
    shown = _json(capsys, str(corpus / eni))
    found = mailbox_state = 0
    for s, el in zip(shown["slaves"], tree.findall("Config/Slave")):
        for ic in el.findall("InitCmds/InitCmd"):
            ado = _num(ic.findtext("Ado"))
            data = bytes.fromhex(ic.findtext("Data") or "")
            if not (0x0600 <= ado < 0x0700 and len(data) == 16 and any(data)):
                continue
            start = int.from_bytes(data[0:4], "little")
            end = start + int.from_bytes(data[4:6], "little") - 1
            kind = {1: "inputs", 2: "outputs"}[data[11]]
            physical = int.from_bytes(data[8:10], "little")
            if 0x0800 <= physical < 0x0900 and physical % 8 == 5:
                # onto SM n's status byte (0x0805 + 8n): the mailbox-state bit
                kind = f"mailbox state of sm {(physical - 0x0805) // 8}"
                mailbox_state += 1
            words = (f"set fmmu {(ado - 0x600) // 16} ({kind}) logical 0x{start:08X}.{data[6]}"
                     f"-0x{end:08X}.{data[7]} -> 0x{int.from_bytes(data[8:10], 'little'):04X}"
                     f".{data[10]}")
            for t in ic.findall("Transition"):
                assert words in s["init_cmds"][t.text], (words, s["init_cmds"][t.text])
            found += 1
    assert found >= 4 and mailbox_state >= 1


def test_show_names_every_register_and_gives_watchdogs_a_time(corpus, capsys):
    """A register command ``show`` has no words of its own for is named from the register
    table (``registers.py``), never left as ``BWR 0x0200``: every command with an Ado in
    the InitCmds of every ENI of both corpora (read here with lxml), and the master's of a
    TwinCAT file in words (ESC Section II names).  The SM watchdog, a count of the
    divider's steps (2498 + 2) x 40 ns = 100 us, with its time."""
    from conftest import corpus_enis, CORPORA
    from ecatcfg.registers import covered
    unnamed = set()
    for name in corpus_enis():
        root, below = name.split("/", 1)
        tree = etree.parse(str(CORPORA[root] / "eni" / below))
        for ic in tree.iter("InitCmd"):
            if ic.findtext("Ado") is None or ic.findtext("Cmd") is None:
                continue
            length = len(bytes.fromhex(ic.findtext("Data") or "")) or int(
                ic.findtext("DataLength") or ic.findtext("Len") or 1)
            if not covered(_num(ic.findtext("Ado")), length):
                unnamed.add((name, ic.findtext("Ado"), length))
    assert not unnamed, sorted(unnamed)[:20]
    eni = corpus / "eni/jn-ec-master/mega_master_eni.xml"
    master = _json(capsys, str(eni))["master_init_cmds"]["IP"]
    assert {"set ECAT event mask = 0x0004", "set DL control byte 3 = 0x00",
            "set DC system time difference filter depth = 0x00, DC speed counter filter "
            "depth = 0x0C", "read AL status"} <= set(master), master
    assert main(["show", str(eni), "--no-cache"]) == 0
    text = capsys.readouterr().out.split("InitCmds", 1)[1]
    import re
    raw = re.findall(r"\b(?:AP|FP|B)(?:RD|WR|RW)\b 0x[0-9A-F]{4}", text)
    assert raw == []
    from ecatcfg.eni.plan import InitCmd
    from ecatcfg.eni.words import init_cmd_words
    from ecatcfg.esc import Transition
    watchdog = InitCmd(transitions=[Transition.PS], comment="", cmd=5, length=2, adp=1001,
                       ado=0x0420, data=(10000).to_bytes(2, "little"))
    assert init_cmd_words(watchdog) == "set SM watchdog 10000 (1000 ms at the default divider)"


def test_show_eni_text(corpus, capsys):
    eni = corpus / "eni/jn-ec-master/mega_master_eni.xml"
    assert main(["show", str(eni)]) == 0
    out = capsys.readouterr().out
    tree = etree.parse(str(eni))
    for s in tree.findall("Config/Slave"):
        assert repr(s.findtext("Info/Name")) in out
    v = tree.find("Config/ProcessImage/Outputs/Variable")
    offs = _num(v.findtext("BitOffs"))
    assert f"{offs // 8}.{offs % 8}" in out and v.findtext("Name") in out
    assert "behind 'Term 1 (EK1100)' port B" in out


PASSIVE_LINE = """
master: {name: passive-line}
slaves:
  - {name: coupler, device: EX1100}
  - {name: feed, device: EX9100}
  - {name: lamps, device: EX2008}
  - {name: cap, device: EX9011}
"""


def test_show_marks_passive_slaves(tmp_path, capsys):
    from conftest import EXAMPLES, FIXTURES
    eni = tmp_path / "line.xml"
    assert main(["compile", str(write(tmp_path, "line.yaml", PASSIVE_LINE)), "--esi",
                 str(EXAMPLES / "esi"), "--esi", str(FIXTURES / "ecatcfg-EX9xxx-passive.xml"),
                 "-o", str(eni), "--no-cache"]) == 0
    capsys.readouterr()
    tree = etree.parse(str(eni))
    passive = [s.findtext("Info/Name") for s in tree.findall("Config/Slave")
               if s.find("Info/PhysAddr") is None]
    assert passive == ["feed", "cap"]
    shown = _json(capsys, str(eni))
    assert [s["name"] for s in shown["slaves"]] == ["coupler", "feed", "lamps", "cap"]
    assert [s["name"] for s in shown["slaves"] if s["passive"]] == passive
    assert all(s["position"] is None and s["init_cmds"] == {}
               for s in shown["slaves"] if s["passive"])
    assert main(["show", str(eni)]) == 0
    assert "  passive    'feed'" in capsys.readouterr().out


def test_show_errors_name_the_file(tmp_path, corpus, capsys):
    assert main(["show", str(corpus / ELMO_ESI)]) == 2
    assert "not an ENI: the root element is <EtherCATInfo> (an ESI: name the device with " \
        "--device), expected <EtherCATConfig>" in capsys.readouterr().err
    broken = write(tmp_path, "broken.xml", "<?xml version='1.0'?>\n<EtherCATConfig>\n<Config>")
    assert main(["show", str(broken), "--no-cache"]) == 1
    err = capsys.readouterr().err
    assert f"{broken}:" in err and "Traceback" not in err
    assert main(["show", str(tmp_path / "missing.xml")]) == 2


def test_show_lists_a_transition_in_the_order_apply_sends_it(tmp_path, capsys):
    """``show`` and ``apply`` take the order from one definition (``eni/sequence.py``); this
    checks them against each other on the wire.  The example drive's PS transition: its SDO
    downloads (PDO assignment and mapping) are on the wire before the AL control write that
    requests SAFEOP (tshark reads the pcap of ``apply --virtual``), in the order ``show``
    lists them, and ``show`` lists the request after them."""
    import subprocess
    import re

    from conftest import EXAMPLES, compile_example
    from rig import require_tshark
    from test_apply import _datagram_trees, _walk, sdo_requests

    eni = compile_example(tmp_path / "line.xml")
    shown = _json(capsys, str(eni))
    [drive] = [s for s in shown["slaves"] if s["name"] == "axis1"]
    ps = drive["init_cmds"]["PS"]
    sdos = [m.group(1, 2) for w in ps if (m := re.match(r"SDO 0x([0-9A-F]{4}):([0-9A-F]{2})", w))]
    assert len(sdos) >= 4
    last_sdo = max(i for i, w in enumerate(ps) if w.startswith("SDO "))
    assert ps.index("request SAFEOP") > last_sdo

    pcap = tmp_path / "line.pcapng"
    assert main(["apply", str(eni), "--virtual", "--esi", str(EXAMPLES / "esi"), "--cycles",
                 "2", "--pcap", str(pcap)]) == 0
    capsys.readouterr()
    station = drive["phys_addr"]
    # The outbound frame that requests SAFEOP of the drive: FPWR 0x0120 = 0x0004.
    proc = subprocess.run([require_tshark(), "-n", "-r", str(pcap), "-T", "json",
                           "--no-duplicate-keys", "-Y",
                           "frame.packet_flags_direction == 2 && ecat.ado == 0x0120"],
                          capture_output=True, text=True, timeout=120)
    requests = []
    for packet in json.loads(proc.stdout):
        layers = packet["_source"]["layers"]
        for ecat in layers["ecat"] if isinstance(layers["ecat"], list) else [layers["ecat"]]:
            for dg in _datagram_trees(ecat):
                if (int(_walk(dg, "ecat.adp"), 16), int(_walk(dg, "ecat.ado"), 16)) == (
                        station, 0x0120) and _walk(dg, "ecat.reg.alctrl.ctrl") == "0x0004":
                    requests.append(int(_walk(layers["frame"], "frame.number")))
    safeop = min(requests)
    sent = [(r["sdoidx"], r["sdosub"], r["frame"]) for r in sdo_requests(pcap)[station]]
    before = [(f"{int(i, 16):04X}", f"{int(s, 16):02X}") for i, s, f in sent if f < safeop]
    # Resends of a lost frame repeat a request; the wire order, once each, is show's order.
    once = [x for k, x in enumerate(before) if k == 0 or before[k - 1] != x]
    assert once == sdos
