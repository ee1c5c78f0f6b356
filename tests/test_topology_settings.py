"""Topology keys for what real ENIs set beyond PDOs and SDOs (docs/compile.md "EoE IP
parameters" and "Watchdogs"): a slave's EoE IP parameters (one set IP parameter request in
``Mailbox/EoE/InitCmds``) and the ESC watchdogs (registers 0x0400, 0x0410, 0x0420 in
INIT->PREOP).

The references are not our code: the EoE InitCmd is compared with the one EC-Engineer
wrote into a real export (Murrelektronik VarioX, read with plain lxml), the watchdog
commands with EC-Engineer's Elmo export and TwinCAT's Copley export; bytes of other requests
are written out by hand from the layout (ETG.1000.6 EoE, ``docs/protocol-notes.md`` §9: an
IPv4 address is a little-endian 32-bit number, so 10.0.0.7 is ``07 00 00 0a``); on the wire
tshark dissects the request, and the emulated slave stores what it was sent.
"""

from __future__ import annotations

import json
import re
import struct
import subprocess
import sys
from ipaddress import IPv4Address
from pathlib import Path

import pytest
from lxml import etree

from conftest import MAILBOX_PD_SMS, device_xml, esi_xml, write
from rig import tshark_fields, tshark_malformed
from ecatcfg import eoe
from ecatcfg.compiler import build, topology
from ecatcfg.compiler.topology import TopologyError
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.esc import AlState
from ecatcfg.esi.library import Library
from ecatcfg.runtime import Network

DEVICES = {"TS-EOE": ("#x30", "<EoE/><CoE/>"),
           "TS-COE": ("#x31", "<CoE/>"),
           "TS-NOIP": ("#x32", '<EoE IP="false" MAC="true"/><CoE/>'),
           # An ESI EoE InitCmd (ETG.2000 schema: Transition+, Type, Data, Comment?).
           "TS-ESICMD": ("#x34", "<EoE><InitCmd><Transition>PS</Transition><Type>2</Type>"
                                 "<Data>0200000001000000020000000007</Data></InitCmd></EoE>")}
# A mailbox of 64 bytes cannot carry the 68-byte request (6 + 4 + 58).
SMALL_MAILBOX = MAILBOX_PD_SMS.replace('DefaultSize="128" Enable="1" StartAddress="#x1000"',
                                       'DefaultSize="64" Enable="1" StartAddress="#x1000"')
# A passive terminal: no ProductCode, nothing an ESC has.
PASSIVE = ('      <Device><Type>TS-PASSIVE</Type><Name LcId="1033">end terminal</Name>'
           '<GroupType>G</GroupType></Device>')


@pytest.fixture(scope="module")
def esi_file(tmp_path_factory) -> Path:
    bodies = [device_xml(name, product, body=MAILBOX_PD_SMS + f"<Mailbox>{mailbox}</Mailbox>")
              for name, (product, mailbox) in DEVICES.items()]
    bodies.append(device_xml("TS-SMALL", "#x33",
                             body=SMALL_MAILBOX + "<Mailbox><EoE/><CoE/></Mailbox>"))
    path = tmp_path_factory.mktemp("settings-esi") / "settings.xml"
    path.write_text(esi_xml(*bodies, PASSIVE))
    return path


def compile_text(text: str, esi: list[Path]):
    return build.compile_topology(topology.loads(text, "t.yaml"),
                                  Library(esi, cache=False)).plan


def errors_of(text: str, esi: list[Path]) -> str:
    with pytest.raises(TopologyError) as err:
        compile_text(text, esi)
    return str(err.value)


def eni_slaves(data: bytes) -> dict[str, etree._Element]:
    root = etree.fromstring(data)
    return {s.findtext("Info/Name"): s for s in root.iter("Slave")}


def element(el: etree._Element) -> tuple:
    """An element as its attributes and children (tag, text), white space aside."""
    return dict(el.attrib), [(c.tag, (c.text or "").strip().lower()) for c in el]


# --------------------------------------------------------------------------- EoE

def test_eoe_is_written_as_ec_engineer_writes_it(esi_file, corpus):
    """EC-Engineer's export sets ip 192.168.0.102/24 and a MAC made of the station address
    (02:00:00:00:03:ea for slave 1002) in IP: the same topology gives the same element."""
    ref = eni_slaves((corpus / "eni/murrelektronik-variox/eni.xml").read_bytes())
    [ref_cmd] = ref["Slave_1002 [54632]"].findall("Mailbox/EoE/InitCmds/InitCmd")
    plan = compile_text("slaves:\n  - {name: head, device: TS-COE}\n"
                        "  - name: eoe\n    device: TS-EOE\n    station_address: 1002\n"
                        "    eoe: {ip: 192.168.0.102/24, mac: auto}\n", [esi_file])
    [ours] = eni_slaves(eni_writer.to_bytes(plan))["eoe"].findall("Mailbox/EoE/InitCmds/InitCmd")
    assert element(ours) == element(ref_cmd)
    assert ours.findtext("Data").startswith("02000000" "07000000" "0200000003ea" "6600a8c0"
                                            "00ffffff")


def test_every_parameter_at_its_fixed_place(esi_file):
    plan = compile_text(
        "slaves:\n  - name: s\n    device: TS-EOE\n    eoe:\n      ip: 10.0.0.7\n"
        "      subnet_mask: 255.255.0.0\n      gateway: 10.0.0.1\n      dns: 10.0.0.2\n"
        "      dns_name: axis1\n      mac: 02-00-00-00-00-07\n", [esi_file])
    [cmd] = plan.slaves[0].mailbox.eoe_init_cmds
    assert cmd.data == bytes.fromhex(
        "02000000" "3f000000" "020000000007" "0700000a" "0000ffff" "0100000a" "0200000a"
        "6178697331") + bytes(27)
    assert (cmd.transitions[0].value, cmd.comment, cmd.timeout, cmd.fixed) == (
        "IP", "eoe init", 0, True)


def test_only_the_given_parameters_are_flagged(esi_file):
    plan = compile_text("slaves:\n  - {name: s, device: TS-EOE, eoe: {gateway: 10.0.0.2}}\n",
                        [esi_file])
    [cmd] = plan.slaves[0].mailbox.eoe_init_cmds
    assert cmd.data == bytes.fromhex("02000000" "08000000") + bytes(6 + 4 + 4) + \
        bytes.fromhex("0200000a") + bytes(4 + 32)


def test_the_eni_is_schema_valid_and_reads_back_equal(esi_file, eni_schema):
    plan = compile_text("master: {watchdog: {sm_ms: 50}}\nslaves:\n"
                        "  - {name: s, device: TS-EOE,\n"
                        "     eoe: {ip: 10.0.0.7/255.0.0.0, dns_name: a}}\n"
                        "  - {name: t, device: TS-COE}\n", [esi_file])
    data = eni_writer.to_bytes(plan)
    assert eni_schema.validate(etree.fromstring(data)), eni_schema.error_log
    again = eni_reader.read_bytes(data, "t.eni.xml")
    assert again == plan
    assert again.slaves[0].mailbox.eoe_init_cmds[0].request.params == eoe.IpParameters(
        ip=IPv4Address("10.0.0.7"), subnet_mask=IPv4Address("255.0.0.0"), dns_name="a")


@pytest.mark.parametrize("slave, message", [
    ("{name: s, device: TS-COE, eoe: {ip: 10.0.0.1}}",
     r"t.yaml:2: slave 's': TS-COE has no EoE mailbox \(its ESI, .*settings.xml:\d+, lists "
     r"CoE\), so IP parameters cannot be set"),
    ("{name: s, device: TS-NOIP, eoe: {ip: 10.0.0.1}}",
     r"t.yaml:2: slave 's': the ESI of TS-NOIP says its EoE has no IP support "
     r"\(EoE IP=\"false\", .*settings.xml:\d+\); only 'mac' can be set"),
    ("{name: s, device: TS-SMALL, eoe: {ip: 10.0.0.1}}",
     r"t.yaml:2: slave 's': its mailbox \(SM0, 64 bytes\) cannot carry the EoE request "
     r"\(68 bytes\)"),
    ("{name: s, device: TS-EOE, eoe: {ip: 10.0.0.256}}",
     r"t.yaml:2: slaves.0.eoe.ip: Value error, '10.0.0.256' is not an IPv4 address"),
    ("{name: s, device: TS-EOE, eoe: {ip: 10.0.0.1/24, subnet_mask: 255.255.0.0}}",
     r"ip 10.0.0.1/24 gives subnet mask 255.255.255.0, subnet_mask says 255.255.0.0"),
    ("{name: s, device: TS-EOE, eoe: {subnet_mask: 255.0.255.0}}",
     r"'255.0.255.0' is not a netmask"),
    ("{name: s, device: TS-EOE, eoe: {ip: 10.0.0.1/0.0.0.255}}",    # a host mask
     r"'0.0.0.255' is not a netmask"),
    ("{name: s, device: TS-EOE, eoe: {mac: 02:00:00:00:03}}",
     r"slaves.0.eoe.mac: .*is not a MAC address"),
    ("{name: s, device: TS-EOE, eoe: {mac: 10:18:20:11:01:04}}",
     r"write the MAC address in quotes"),
    ("{name: s, device: TS-EOE, eoe: {mac: '01:00:5e:00:00:01'}}",
     r"is a group \(multicast\) address"),
    ("{name: s, device: TS-EOE, eoe: {dns_name: " + "x" * 33 + "}}",
     r"has 33 characters; the set IP parameter request holds 32"),
    ("{name: s, device: TS-EOE, eoe: {}}", r"sets nothing"),
    ("{name: s, device: TS-EOE, eoe: {ipaddr: 10.0.0.1}}", r"slaves.0.eoe.ipaddr: unknown key"),
    ("{name: s, device: TS-PASSIVE, eoe: {ip: 10.0.0.1}}",
     r"passive terminal .*it cannot have EoE IP parameters; 'eoe' must go"),
    ("{name: s, device: TS-ESICMD}",
     r"t.yaml:2: slave 's': the ESI of TS-ESICMD has EoE InitCmds \(.*settings.xml:\d+\), "
     r"which ecatcfg does not implement and would not send"),
    ("{name: s, device: TS-PASSIVE, watchdog: {}}",
     r"it cannot have watchdogs; 'watchdog' must go"),
])
def test_mistakes_are_errors_at_the_line(esi_file, slave, message):
    text = f"slaves:\n  - {slave}\n"
    if "PASSIVE" in slave:
        text = "slaves:\n  - {name: head, device: TS-EOE}\n" + text.split("\n", 1)[1]
    assert re.search(message, errors_of(text, [esi_file]))


def test_only_the_mac_on_a_device_without_ip_support(esi_file):
    plan = compile_text("slaves:\n  - {name: s, device: TS-NOIP, station_address: 300, "
                        "eoe: {mac: auto}}\n", [esi_file])
    [cmd] = plan.slaves[0].mailbox.eoe_init_cmds
    assert cmd.request.params == eoe.IpParameters(mac=bytes.fromhex("02000000012c"))


def test_the_json_schema_takes_the_keys_and_refuses_bad_values():
    import jsonschema
    schema = topology.json_schema()
    good = {"master": {"watchdog": {"sm_ms": 50}},
            "slaves": [{"name": "s", "device": "TS-EOE", "watchdog": {"divider": "0x9C2"},
                        "eoe": {"ip": "10.0.0.7/24", "gateway": "10.0.0.1",
                                "dns": "10.0.0.2", "dns_name": "s1",
                                "mac": "02:00:00:00:00:07"}}]}
    jsonschema.validate(good, schema, format_checker=jsonschema.FormatChecker())
    for slave in ({"eoe": {"gateway": "10.0.0"}}, {"eoe": {"mac": "02:00:00:00:07"}},
                  {"eoe": {"dns_name": "x" * 33}}, {"eoe": {"ipaddr": "10.0.0.1"}},
                  {"watchdog": {"sm_ms": -1}}, {"watchdog": {"multiplier": 2498}}):
        bad = {"slaves": [{"name": "s", "device": "TS-EOE", **slave}]}
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, schema, format_checker=jsonschema.FormatChecker())


# --------------------------------------------------------------------------- watchdogs

WATCHDOG_COMMENTS = ("set watchdog divider", "set PDI watchdog", "set SM watchdog")


def ref_register_cmds(slave: etree._Element) -> list[tuple]:
    """(comment, transitions, cmd, adp, ado, data, cnt, retries, requires) of each register
    InitCmd, in file order."""
    return [(c.findtext("Comment"), tuple(t.text for t in c.findall("Transition")),
             int(c.findtext("Cmd")), int(c.findtext("Adp")), int(c.findtext("Ado")),
             c.findtext("Data") or "00" * int(c.findtext("DataLength")),
             c.findtext("Cnt"), c.findtext("Retries"), c.findtext("Requires"))
            for c in slave.findall("InitCmds/InitCmd")]


def by_transition(cmds: list[tuple]) -> dict[str, list[tuple]]:
    """Each transition's commands in execution (file) order: what a master runs (the files
    interleave transitions in different orders)."""
    out: dict[str, list[tuple]] = {}
    for comment, transitions, *rest in cmds:
        for t in transitions:
            out.setdefault(t, []).append((comment, *rest))
    return out


ELMO = """
master: {name: rocos, cycle_time_us: 1000}
slaves:
  - name: "Slave_1001 [Elmo Drive ]"
    device: "0x9a:0x30924:0x10420"
    rx_pdos: [0x160A, 0x160B, 0x160C, 0x160F, 0x161C]
    tx_pdos: [0x1A0A, 0x1A0E, 0x1A11, 0x1A13, 0x1A1D]
    dc: DC Sync
    watchdog: {sm_ms: 1000}
"""


def test_elmo_register_commands_equal_ec_engineers_with_its_watchdogs(corpus):
    """EC-Engineer sets the Elmo Gold's SM watchdog to 1 s (0x2710 x 100 us): with
    ``watchdog: {sm_ms: 1000}`` every register InitCmd of every transition is the export's."""
    name = "Slave_1001 [Elmo Drive ]"
    ref = eni_slaves((corpus / "eni/rocos-ethercat/eni.xml").read_bytes())[name]
    plan = compile_text(ELMO, [corpus / "esi/drives/Elmo_ECAT_00010420_V11.xml"])
    ours = eni_slaves(eni_writer.to_bytes(plan))[name]
    assert by_transition(ref_register_cmds(ours)) == by_transition(ref_register_cmds(ref))
    assert [c[5] for c in ref_register_cmds(ours) if c[0] in WATCHDOG_COMMENTS] == [
        "c209", "e803", "1027"]


def test_the_defaults_are_what_twincat_writes_for_the_copley_drive(esi_file, corpus):
    """``watchdog: {}`` writes the ESC's power-on values, as the TwinCAT-style Copley export
    does (2498, 1000, 1000), in the same place: right after the station address."""
    ref = next(iter(eni_slaves(
        (corpus / "eni/acontis-ecmaster-demo-motion/Copley_AEP.xml").read_bytes()).values()))
    plan = compile_text("slaves:\n  - {name: s, device: TS-EOE, watchdog: {}}\n", [esi_file])
    ours = eni_slaves(eni_writer.to_bytes(plan))["s"]

    def after_address(cmds: list[tuple]) -> list[tuple]:
        ip = [c for c in cmds if "IP" in c[1]]
        at = next(i for i, c in enumerate(ip) if c[0] == "set physical address")
        return ip[at + 1:at + 4]

    assert after_address(ref_register_cmds(ours)) == after_address(ref_register_cmds(ref))
    assert [c[0] for c in after_address(ref_register_cmds(ours))] == list(WATCHDOG_COMMENTS)


def test_without_watchdog_keys_nothing_is_written(esi_file):
    plan = compile_text("slaves:\n  - {name: s, device: TS-EOE}\n", [esi_file])
    assert not [c for c in plan.slaves[0].init_cmds if 0x0400 <= (c.ado or 0) < 0x0440]


def watchdog_values(plan, slave: int) -> list[int]:
    return [struct.unpack("<H", c.payload)[0] for c in plan.slaves[slave].init_cmds
            if c.comment in WATCHDOG_COMMENTS]


def test_the_master_gives_every_slave_its_watchdogs_and_a_slave_its_own_keys(esi_file):
    plan = compile_text(
        "master: {watchdog: {divider: 498, pdi_ms: 0}}\nslaves:\n"
        "  - {name: a, device: TS-EOE}\n"
        "  - {name: b, device: TS-COE, watchdog: {sm_ms: 2.5, divider: 2498}}\n"
        "  - {name: c, device: TS-COE, watchdog: {sm_ms: 0.06}}\n", [esi_file])
    # divider 498: (498 + 2) x 40 ns = 20 us, the default 100 ms = 5000; 2.5 ms at 100 us
    # = 25; 0.06 ms at 20 us = 3.
    assert watchdog_values(plan, 0) == [498, 0, 5000]
    assert watchdog_values(plan, 1) == [2498, 0, 25]
    assert watchdog_values(plan, 2) == [498, 0, 3]


@pytest.mark.parametrize("text, message", [
    ("slaves:\n  - {name: s, device: TS-EOE, watchdog: {sm_ms: 0.25}}\n",
     "t.yaml:2: slave 's': watchdog sm_ms 0.25: not a whole number of watchdog time bases of "
     "100 us (the nearest are 0.2 and 0.3 ms)"),
    ("slaves:\n  - {name: s, device: TS-EOE, watchdog: {pdi_ms: 6553.6}}\n",
     "t.yaml:2: slave 's': watchdog pdi_ms 6553.6: 65536 time bases of 100 us; register "
     "0x0410 holds at most 65535 (6553.5 ms)"),
    # The master's value, at the master's line: (0 + 2) x 40 ns = 80 ns, 10 ms = 125000.
    ("master:\n  watchdog:\n    divider: 0\n    sm_ms: 10\nslaves:\n"
     "  - {name: s, device: TS-EOE}\n",
     "t.yaml:4: slave 's': watchdog sm_ms 10: 125000 time bases of 80 ns; register 0x0420 "
     "holds at most 65535 (5.2428 ms)"),
    # The default 100 ms does not fit an 80 ns base: said at the divider's line.
    ("slaves:\n  - name: s\n    device: TS-EOE\n    watchdog:\n      sm_ms: 1\n"
     "      divider: 0\n",
     "t.yaml:6: slave 's': watchdog pdi_ms 100 (the default; give it): 1250000 time bases of "
     "80 ns; register 0x0410 holds at most 65535 (5.2428 ms)"),
    ("slaves:\n  - {name: s, device: TS-EOE, watchdog: {sm_ms: true}}\n",
     "t.yaml:2: slaves.0.watchdog.sm_ms: Value error, expected a number, not true/false"),
    ("slaves:\n  - {name: s, device: TS-EOE, watchdog: {sm_ms: -1}}\n",
     "t.yaml:2: slaves.0.watchdog.sm_ms: Input should be greater than or equal to 0"),
    ("slaves:\n  - {name: s, device: TS-EOE, watchdog: {divider: 0x10000}}\n",
     "t.yaml:2: slaves.0.watchdog.divider: Input should be less than or equal to 65535"),
])
def test_watchdog_mistakes_are_errors_at_the_line(esi_file, text, message):
    assert message in errors_of(text, [esi_file])


# --------------------------------------------------------------------------- on the wire

TOPOLOGY = """
master: {watchdog: {sm_ms: 5000}}
slaves:
  - name: drive
    device: TS-EOE
    eoe: {ip: 192.168.7.21/24, gateway: 192.168.7.1, dns_name: drive-1, mac: auto}
    watchdog: {pdi_ms: 250}
  - {name: io, device: TS-COE}
"""


def test_the_emulated_slave_holds_what_the_topology_set(esi_file, tmp_path):
    plan = compile_text(TOPOLOGY, [esi_file])
    eni = write(tmp_path, "t.eni.xml", eni_writer.to_bytes(plan))
    with Network.virtual(eni, esi=[esi_file], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        drive, io = net.segment.slaves
        assert drive.eoe_ip == eoe.IpParameters(
            mac=bytes.fromhex("0200000003e9"), ip=IPv4Address("192.168.7.21"),
            subnet_mask=IPv4Address("255.255.255.0"),
            default_gateway=IPv4Address("192.168.7.1"), dns_name="drive-1")
        assert io.eoe_ip is None
        # 0x0400, 0x0410, 0x0420 as the master wrote them: 2498, 250 ms and 5 s at 100 us.
        assert [struct.unpack_from("<H", s.mem, a)[0] for s in (drive, io)
                for a in (0x0400, 0x0410, 0x0420)] == [2498, 2500, 50000, 2498, 1000, 50000]
        # The ESC runs its SM watchdog with them: half a second without outputs expires the
        # power-on 100 ms, not the 5 s the topology set.
        later = net.clock.monotonic() + 0.5
        for slave in (drive, io):
            slave.check_watchdog(later)
            assert (slave.state, slave.error) == (AlState.OP, False)
        net.down()


def test_tshark_reads_our_request_as_set_ip_parameter(esi_file, tmp_path, tshark_path):
    topo = write(tmp_path, "t.yaml", TOPOLOGY)
    eni, pcap = tmp_path / "t.eni.xml", tmp_path / "t.pcapng"
    run = [sys.executable, "-m", "ecatcfg"]
    done = subprocess.run(run + ["compile", str(topo), "--esi", str(esi_file), "-o", str(eni),
                                 "--no-cache"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    done = subprocess.run(run + ["apply", str(eni), "--virtual", "--esi", str(esi_file),
                                 "--simulated-time", "--cycles", "5", "--pcap", str(pcap),
                                 "--format", "json",
                                 "--no-cache"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert "EoE IP parameters of 'drive' set: ip 192.168.7.21/255.255.255.0, gateway " \
           "192.168.7.1, name 'drive-1', mac 02:00:00:00:03:e9" in report["events"]
    fields = ["ecat_mailbox.eoe.type", "ecat_mailbox.eoe.init.ipaddr",
              "ecat_mailbox.eoe.init.subnetmask", "ecat_mailbox.eoe.init.defaultgateway",
              "ecat_mailbox.eoe.init.dnsname", "ecat_mailbox.eoe.init.macaddr"]
    rows = {tuple(v[0] if v else "" for v in p.values())
            for p in tshark_fields(pcap, fields, display_filter="ecat_mailbox.eoe")}
    assert rows == {("2", "192.168.7.21", "255.255.255.0", "192.168.7.1", "drive-1",
                     "02:00:00:00:03:e9"), ("3", "", "", "", "", "")}
    # The watchdog writes, as tshark names the registers (FPWR to stations 1001 and 1002).
    registers = ["ecat.reg.wd.divisor", "ecat.reg.wd.timepdi", "ecat.reg.wd.timesm"]
    writes = set()
    for p in tshark_fields(pcap, ["ecat.cmd", "ecat.adp", *registers],
                           display_filter=" || ".join(registers)):
        for register in registers:
            if p[register]:
                assert len(p[register]) == len(p["ecat.adp"]) and set(p["ecat.cmd"]) == {"0x05"}
                writes |= {(adp, register.rsplit(".", 1)[1], value)
                           for adp, value in zip(p["ecat.adp"], p[register])}
    assert writes == {("0x03e9", "divisor", "0x09c2"), ("0x03e9", "timepdi", "0x09c4"),
                      ("0x03e9", "timesm", "0xc350"), ("0x03ea", "divisor", "0x09c2"),
                      ("0x03ea", "timepdi", "0x03e8"), ("0x03ea", "timesm", "0xc350")}
    assert tshark_malformed(pcap) == []
