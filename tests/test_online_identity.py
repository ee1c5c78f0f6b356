"""``states``, ``doctor`` and ``graph --iface`` without an ENI say who each slave is: the
identity in its SII (vendor, product, revision), the device name from the SII or, with
``--esi``, from the ESI file.

The line is the example coupler, digital input and drive emulated over veth; what the
commands print is compared with the ESI files read here with lxml (Vendor/Id,
Device/Type@ProductCode/RevisionNo, Type and Name), not with the package's ESI reader.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from lxml import etree
from rig import serving

from ecatcfg.esi.library import Library
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
LINE = ["EX1100", "EX1004", "EXD-402"]


def _number(text: str) -> int:
    return int(text.strip()[2:], 16) if text.strip().startswith("#x") else int(text)


def esi_identities() -> dict[str, dict]:
    """Type -> {vendor, product, revision, name} over the example ESI files."""
    out = {}
    for path in ESI.glob("*.xml"):
        root = etree.parse(str(path)).getroot()
        vendor = _number(root.findtext("Vendor/Id"))
        for device in root.iter("Device"):
            t = device.find("Type")
            out[t.text.strip()] = {"vendor": vendor, "product": _number(t.get("ProductCode")),
                                   "revision": _number(t.get("RevisionNo")),
                                   "name": device.findtext("Name").strip()}
    return out


@pytest.fixture(scope="module")
def line():
    lib = Library([ESI], cache=False)
    return lambda: segment([SlaveSpec(lib.device(lib.find(s).entry), f"s{i}")
                            for i, s in enumerate(LINE)])


def run(rig, *argv: str):
    done = rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", *argv, "--iface", rig.if_a],
                      timeout=90, cwd=ROOT)
    assert "Traceback" not in done.stderr, done.stderr
    return done


def selector(ident: dict) -> str:
    return f"0x{ident['vendor']:08x}:0x{ident['product']:08x}:0x{ident['revision']:08x}"


def test_states_and_doctor_show_identities(veth_netns, line):
    ids = esi_identities()
    with serving(veth_netns, line()):
        plain = run(veth_netns, "states")
        named = run(veth_netns, "states", "--esi", str(ESI), "--format", "json")
        one = run(veth_netns, "states", "--slave", "2", "--esi", str(ESI))
        doctor = run(veth_netns, "doctor")
        doctor_esi = run(veth_netns, "doctor", "--esi", str(ESI), "--format", "json")
    assert plain.returncode == 0, plain.stderr
    lines = plain.stdout.splitlines()
    assert len(lines) == 3
    for k, (text, t) in enumerate(zip(lines, LINE)):
        assert text.split() == [str(k), selector(ids[t]), "INIT"], text
    rows = json.loads(named.stdout)["slaves"]
    assert [(r["vendor_id"], r["product_code"], r["revision"], r["type"], r["name"])
            for r in rows] == [(ids[t]["vendor"], ids[t]["product"], ids[t]["revision"], t,
                                ids[t]["name"]) for t in LINE]
    assert one.stdout.split() == ["2", selector(ids["EXD-402"]), "EXD-402", "INIT"]

    # doctor: every slave is in INIT, not OP; each is named by its identity.
    assert doctor.returncode == 1
    for k, t in enumerate(LINE):
        assert f"slave {k} ({selector(ids[t])}): INIT, not OP" in doctor.stdout, \
            doctor.stdout
    findings = json.loads(doctor_esi.stdout)["findings"]
    assert [(f["vendor_id"], f["product_code"], f["revision"], f["type"]) for f in findings] \
        == [(ids[t]["vendor"], ids[t]["product"], ids[t]["revision"], t) for t in LINE]


def test_graph_of_a_live_line_shows_names(veth_netns, line):
    ids = esi_identities()
    with serving(veth_netns, line()):
        sii = run(veth_netns, "graph", "--format", "json")
        esi = run(veth_netns, "graph", "--esi", str(ESI), "--format", "json")
        dot = run(veth_netns, "graph", "--esi", str(ESI))
    for done in (sii, esi, dot):
        assert done.returncode == 0, done.stderr
    # From the SII alone: its device name (the emulation writes the ESI's Name there, as
    # a real slave's SII holds its vendor's); with --esi the ESI's Type and Name.
    labels = [n["label"] for n in json.loads(sii.stdout)["nodes"][1:]]
    assert [lb.split("\n") for lb in labels] == [[f"#{k} {t}", ids[t]["name"]]
                                                for k, t in enumerate(LINE)]
    labels = [n["label"] for n in json.loads(esi.stdout)["nodes"][1:]]
    assert [lb.split("\n") for lb in labels] == [[f"#{k} {t}", ids[t]["name"]]
                                                for k, t in enumerate(LINE)]
    assert '"#2 EXD-402\\nEXD-402 servo drive, CiA 402 (example)"' in dot.stdout
