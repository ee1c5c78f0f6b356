"""The reader's tolerance rules and its handling of malformed files, on self-written fixtures."""


import pytest

from conftest import device_xml, esi_xml, write
from ecatcfg.esi.reader import EsiReadError, read_file
from ecatcfg.esi.xmlsafe import XmlError

PDO_BODY = """
<Fmmu>Outputs</Fmmu><Fmmu Sm="3" OpOnly="true">Inputs</Fmmu><Fmmu>MBoxState</Fmmu>
<Sm StartAddress="#x1000" ControlByte="#x26" DefaultSize="128" MinSize="34" MaxSize="256"
    Enable="1">MBoxOut</Sm>
<Sm StartAddress="0x1080" ControlByte="0x22" DefaultSize="128" Enable="true">MBoxIn</Sm>
<Sm StartAddress="4352" ControlByte="100" Enable="1" OpOnly="1">Outputs</Sm>
<Sm StartAddress="#x1180" ControlByte="#x20" Enable="1" Virtual="false">Inputs</Sm>
<RxPdo Fixed="true" Mandatory="1" Sm="2">
  <Index>#x1600</Index><Name>Out</Name><Exclude>#x1601</Exclude>
  <Entry><Index>#x7000</Index><SubIndex>1</SubIndex><BitLen>1</BitLen><Name>Bit</Name>
    <DataType>BOOL</DataType></Entry>
  <Entry><Index>0</Index><BitLen>7</BitLen></Entry>
</RxPdo>
<RxPdo Sm="2" OSFac="4" OSMin="1" OSMax="8"><Index>0x1601</Index><Name>Out2</Name>
  <Exclude>5632</Exclude></RxPdo>
<TxPdo Fixed="0" Sm="3"><Index>6656</Index><Name LcId="1031">Eingang</Name>
  <Name LcId="1033">Input</Name>
  <Entry><Index>#x6000</Index><SubIndex>#x01</SubIndex><BitLen>16</BitLen><Name>Word</Name>
    <DataType>UINT</DataType></Entry>
</TxPdo>
<Mailbox DataLinkLayer="1"><EoE/><CoE SdoInfo="true" PdoAssign="1" PdoConfig="false"
    CompleteAccess="0" SegmentedSdo="true"><InitCmd CompleteAccess="1"><Transition>PS</Transition>
    <Transition>IP</Transition><Index>#x6060</Index><SubIndex>0</SubIndex><Data>08</Data>
    </InitCmd></CoE><FoE/></Mailbox>
<Dc><OpMode><Name>DC</Name><Desc>Sync0</Desc><AssignActivate>#x300</AssignActivate>
  <CycleTimeSync0 Factor="1">0</CycleTimeSync0><ShiftTimeSync0>1000</ShiftTimeSync0>
  <CycleTimeSync1 Factor="-2">0</CycleTimeSync1></OpMode></Dc>
<Eeprom><ByteSize>2048</ByteSize><ConfigData>080E00CC88130000</ConfigData>
  <BootStrap>0010800080108000</BootStrap></Eeprom>
"""


def test_every_part_of_a_device_is_read(tmp_path):
    path = write(tmp_path, "dev.xml", esi_xml(device_xml(body=PDO_BODY)))
    esi = read_file(path)
    assert esi.problems == [] and esi.ignored == []
    dev, = esi.devices
    assert (dev.vendor.id, dev.product_code, dev.revision) == (0xE0F1, 0x10, 1)
    assert [f.type for f in dev.fmmus] == ["Outputs", "Inputs", "MBoxState"]
    assert dev.fmmus[1].sm == 3 and dev.fmmus[1].op_only
    sm = dev.sms
    assert [s.start_address for s in sm] == [0x1000, 0x1080, 0x1100, 0x1180]
    assert [s.control_byte for s in sm] == [0x26, 0x22, 0x64, 0x20]
    assert sm[0].min_size == 34 and sm[0].max_size == 256 and sm[1].enable == 1
    assert sm[2].op_only and not sm[3].virtual and sm[0].is_mailbox
    rx0, rx1 = dev.rx_pdos
    assert rx0.fixed and rx0.mandatory and rx0.sm == 2 and rx0.excludes == [0x1601]
    assert [e.is_padding for e in rx0.entries] == [False, True]
    assert rx0.bit_length == 8 and rx0.entries[1].subindex is None
    assert (rx1.index, rx1.excludes, rx1.os_fac, rx1.os_max) == (0x1601, [0x1600], 4, 8)
    tx, = dev.tx_pdos
    assert tx.index == 0x1A00 and not tx.fixed and tx.name == "Input"
    assert tx.names == {1031: "Eingang", 1033: "Input"}
    assert dev.mailbox.protocols == ["EoE", "CoE", "FoE"] and dev.mailbox.data_link_layer
    coe = dev.mailbox.coe
    assert coe.sdo_info and coe.pdo_assign and not coe.pdo_config and coe.segmented_sdo
    cmd, = coe.init_cmds
    assert (cmd.transitions, cmd.index, cmd.data, cmd.complete_access) == \
        (["PS", "IP"], 0x6060, b"\x08", True)
    mode, = dev.dc.opmodes
    assert (mode.assign_activate, mode.cycle_time_sync0_factor, mode.shift_time_sync0,
            mode.cycle_time_sync1_factor) == (0x300, 1, 1000, -2)
    assert dev.eeprom.byte_size == 2048 and dev.eeprom.config_data[:2] == b"\x08\x0e"


def test_every_object_remembers_file_and_line(tmp_path):
    path = write(tmp_path, "dev.xml", esi_xml(device_xml(body=PDO_BODY)))
    text = path.read_text().splitlines()
    dev = read_file(path, shown_as="shown.xml").devices[0]
    for obj, needle in [(dev, "<Device "), (dev.sms[2], 'StartAddress="4352"'),
                        (dev.rx_pdos[1], 'OSFac="4"'), (dev.tx_pdos[0].entries[0], "<Entry><Index>#x6000"),
                        (dev.mailbox.coe.init_cmds[0], "<InitCmd"), (dev.dc.opmodes[0], "<OpMode>")]:
        assert obj.source.file == "shown.xml"
        assert needle in text[obj.source.line - 1], (obj, needle)


@pytest.mark.parametrize("encoding,prefix", [("UTF-8", b""), ("UTF-8", b"\xef\xbb\xbf"),
                                             ("ISO-8859-1", b""), ("ISO8859-1", b"")])
def test_encodings(tmp_path, encoding, prefix):
    xml = esi_xml(device_xml(type_name="Ger\u00e4t"), encoding=encoding)
    data = prefix + xml.encode("utf-8" if encoding == "UTF-8" else "latin-1")
    dev = read_file(write(tmp_path, "e.xml", data)).devices[0]
    assert dev.type_name == "Ger\u00e4t"


def test_several_devices_and_revisions_in_one_file(tmp_path):
    esi = read_file(write(tmp_path, "m.xml", esi_xml(
        device_xml("A", "#x10", "#x1"), device_xml("A", "#x10", "#x2"),
        device_xml("B ", "16", "0x3"))))
    assert [(d.type_name, d.product_code, d.revision) for d in esi.devices] == \
        [("A", 16, 1), ("A", 16, 2), ("B", 16, 3)]


def test_unknown_elements_are_kept_for_lint(tmp_path):
    body = "<Sm StartAddress='#x1000'>MBoxOut<Bogus/></Sm><Frobnicate>1</Frobnicate>" \
           "<RxPdo><Index>#x1600</Index><Name>x</Name><Gizmo/></RxPdo><URL>ok</URL>"
    esi = read_file(write(tmp_path, "u.xml", esi_xml(device_xml(body=body))))
    assert [(i.tag, i.parent) for i in esi.ignored] == [("Frobnicate", "Device"),
                                                        ("Gizmo", "RxPdo")]
    assert esi.devices[0].rx_pdos[0].index == 0x1600      # reading went on


def test_default_namespace_is_tolerated(tmp_path):
    xml = esi_xml().replace('<EtherCATInfo Version="1.17">',
                            '<EtherCATInfo xmlns="urn:example" Version="1.17">')
    assert read_file(write(tmp_path, "ns.xml", xml)).devices[0].type_name == "FX1"


def test_bad_number_is_a_problem_with_its_line(tmp_path):
    xml = esi_xml(device_xml(product="#xZZ", body="<Sm StartAddress='12x'>Inputs</Sm>"))
    esi = read_file(write(tmp_path, "bad.xml", xml), shown_as="bad.xml")
    assert esi.devices[0].product_code is None and esi.devices[0].sms[0].start_address is None
    (p1, p2) = esi.problems
    line = next(i for i, t in enumerate(xml.splitlines(), 1) if "#xZZ" in t)
    assert (p1.severity, p1.source) == ("error", ("bad.xml", line))
    assert "Type/@ProductCode" in p1.message and "'#xZZ'" in p1.message
    assert p2.severity == "warning" and "Sm/@StartAddress" in p2.message


def test_truncated_xml_names_file_and_line(tmp_path):
    xml = esi_xml()
    path = write(tmp_path, "cut.xml", xml[: len(xml) // 2])
    with pytest.raises(XmlError) as err:
        read_file(path, shown_as="cut.xml")
    assert err.value.file == "cut.xml" and err.value.line > 1
    assert str(err.value).startswith(f"cut.xml:{err.value.line}:") and "not well-formed" in str(err.value)


def test_wrong_root_element(tmp_path):
    path = write(tmp_path, "eni.xml", '<?xml version="1.0"?>\n<EtherCATConfig/>')
    with pytest.raises(EsiReadError, match=r"eni.xml:2: root element is <EtherCATConfig>"):
        read_file(path, shown_as="eni.xml")


def test_entity_bomb_is_rejected_fast(tmp_path):
    ents = "".join(f'<!ENTITY l{i} "{("&l%d;" % (i - 1)) * 10 if i else "lol"}">'
                   for i in range(10))
    xml = f'<?xml version="1.0"?>\n<!DOCTYPE EtherCATInfo [{ents}]>\n' \
          "<EtherCATInfo><Vendor><Id>&l9;</Id></Vendor></EtherCATInfo>"
    path = write(tmp_path, "bomb.xml", xml)
    # Refused by libxml2's entity amplification limit, before the billion "lol"s exist.
    with pytest.raises(XmlError, match=r"bomb.xml:1:\d+: .*entity amplification"):
        read_file(path)


def test_external_entity_is_never_read(tmp_path):
    secret = write(tmp_path, "secret.txt", "TOP-SECRET-CONTENT")
    xml = (f'<?xml version="1.0"?>\n<!DOCTYPE EtherCATInfo [<!ENTITY xxe SYSTEM "file://{secret}">]>\n'
           "<EtherCATInfo><Vendor><Id>1</Id><Name>&xxe;</Name></Vendor></EtherCATInfo>")
    path = write(tmp_path, "xxe.xml", xml)
    with pytest.raises(XmlError) as err:
        read_file(path)
    assert "entity" in str(err.value) and "TOP-SECRET" not in str(err.value)
