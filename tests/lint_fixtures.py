"""Self-written ESI fixtures for the lint rules: one failing and one passing file per rule.

Every fixture is a variation of one small CoE device (``drive()``), changed in one place.  In
a failing fixture the line that must be reported carries the comment ``<!--@-->``.  Passing
fixtures must be free of findings and valid against the ETG.2000 schema (tests check both).
"""

from __future__ import annotations

from dataclasses import dataclass

MARK = "<!--@-->"

PROFILE = """<Profile><ProfileNo>5001</ProfileNo><Dictionary>
<DataTypes>
<DataType><Name>USINT</Name><BitSize>8</BitSize></DataType>
<DataType><Name>UINT</Name><BitSize>16</BitSize></DataType>
<DataType><Name>DINT</Name><BitSize>32</BitSize></DataType>
<DataType><Name>DT7010</Name><BitSize>48</BitSize>
<SubItem><SubIdx>0</SubIdx><Name>Entries</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>0</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
<SubItem><SubIdx>1</SubIdx><Name>Value</Name><Type>DINT</Type><BitSize>32</BitSize><BitOffs>16</BitOffs><Flags><Access>rw</Access><PdoMapping>R</PdoMapping></Flags></SubItem>
</DataType>
</DataTypes>
<Objects>
<Object><Index>#x6000</Index><Name>Input</Name><Type>UINT</Type><BitSize>16</BitSize><Flags><Access>ro</Access><PdoMapping>T</PdoMapping></Flags></Object>
<Object><Index>#x7000</Index><Name>Output</Name><Type>UINT</Type><BitSize>16</BitSize><Flags><Access>rw</Access><PdoMapping>R</PdoMapping></Flags></Object>
<Object><Index>#x7010</Index><Name>Record</Name><Type>DT7010</Type><BitSize>48</BitSize><Flags><Access>rw</Access></Flags></Object>
<Object><Index>#x8000</Index><Name>Setting</Name><Type>UINT</Type><BitSize>16</BitSize><Flags><Access WriteRestrictions="PreOp">rw</Access></Flags></Object>
</Objects>
</Dictionary></Profile>"""

FMMUS = "<Fmmu>Outputs</Fmmu>\n<Fmmu>Inputs</Fmmu>\n<Fmmu>MBoxState</Fmmu>"
SM0 = '<Sm ControlByte="#x26" DefaultSize="128" Enable="1" StartAddress="#x1000">MBoxOut</Sm>'
SM1 = '<Sm ControlByte="#x22" DefaultSize="128" Enable="1" StartAddress="#x1080">MBoxIn</Sm>'
SM2 = '<Sm ControlByte="#x64" DefaultSize="2" Enable="1" StartAddress="#x1100">Outputs</Sm>'
SM3 = '<Sm ControlByte="#x20" DefaultSize="2" Enable="1" StartAddress="#x1180">Inputs</Sm>'
RXPDO = """<RxPdo Mandatory="1" Sm="2"><Index>#x1600</Index><Name>Outputs</Name>
<Entry><Index>#x7000</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Output</Name><DataType>UINT</DataType></Entry>
</RxPdo>"""
TXPDO = """<TxPdo Mandatory="1" Sm="3"><Index>#x1A00</Index><Name>Inputs</Name>
<Entry><Index>#x6000</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Input</Name><DataType>UINT</DataType></Entry>
</TxPdo>"""
MAILBOX = """<Mailbox><CoE SdoInfo="1" PdoAssign="1">
<InitCmd><Transition>PS</Transition><Index>#x8000</Index><SubIndex>0</SubIndex><Data>0100</Data></InitCmd>
</CoE></Mailbox>"""
DC = """<Dc><OpMode><Name>DC</Name><Desc>DC-synchron</Desc><AssignActivate>#x300</AssignActivate>
<CycleTimeSync0 Factor="1">0</CycleTimeSync0><ShiftTimeSync0>0</ShiftTimeSync0></OpMode></Dc>"""
EEPROM = "<Eeprom><ByteSize>2048</ByteSize><ConfigData>080E00CC88130000</ConfigData></Eeprom>"


def drive(type_name: str = "FX1", product: str = "#x10", revision: str = "#x1",
          names: str = '<Name LcId="1033">FX1 test drive</Name>', **parts: str) -> str:
    """The reference device; keyword parts replace its pieces (profile, fmmus, sm0..sm3,
    rx, tx, mailbox, dc, slots, eeprom)."""
    p = dict(profile=PROFILE, fmmus=FMMUS, sm0=SM0, sm1=SM1, sm2=SM2, sm3=SM3, rx=RXPDO,
             tx=TXPDO, mailbox=MAILBOX, dc=DC, slots="", eeprom=EEPROM)
    p.update(parts)
    body = "\n".join(p[k] for k in ("profile", "fmmus", "sm0", "sm1", "sm2", "sm3", "rx", "tx",
                                    "mailbox", "dc", "slots", "eeprom") if p[k])
    return (f'<Device Physics="YY">\n<Type ProductCode="{product}" RevisionNo="{revision}">'
            f"{type_name}</Type>\n{names}\n<GroupType>G</GroupType>\n{body}\n</Device>")


def esi(*devices: str, modules: str = "", head: str = "",
        vendor_name: str = '<Name>Fixture Vendor</Name>') -> str:
    mods = f"<Modules>\n{modules}\n</Modules>\n" if modules else ""
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<EtherCATInfo Version="1.17">\n{head}'
            f"<Vendor><Id>#xE0F1</Id>{vendor_name}</Vendor>\n<Descriptions>\n"
            f"<Groups><Group><Type>G</Type><Name>Group</Name></Group></Groups>\n"
            f"<Devices>\n{chr(10).join(devices or (drive(),))}\n</Devices>\n{mods}"
            f"</Descriptions>\n</EtherCATInfo>\n")


def module(ident: str, name: str = "M") -> str:
    return f'<Module><Type ModuleIdent="{ident}">{name}{ident}</Type><Name>{name}</Name></Module>'


def slots(ident: str) -> str:
    return (f'<Slots><Slot MinInstances="0" MaxInstances="1"><Name>Slot 1</Name>\n'
            f"{ident}</Slot></Slots>")


def rx(index: str = "#x1600", entry: str = "", attrs: str = 'Mandatory="1" Sm="2"',
       extra: str = "") -> str:
    entry = entry or ('<Entry><Index>#x7000</Index><SubIndex>0</SubIndex><BitLen>16</BitLen>'
                      '<Name>Output</Name><DataType>UINT</DataType></Entry>')
    return f"<RxPdo {attrs}><Index>{index}</Index><Name>Outputs</Name>{extra}\n{entry}\n</RxPdo>"


def entry(index: str, sub: int, bits: int, dtype: str, mark: bool = False) -> str:
    return (f"{MARK if mark else ''}<Entry><Index>{index}</Index><SubIndex>{sub}</SubIndex>"
            f"<BitLen>{bits}</BitLen><Name>E</Name><DataType>{dtype}</DataType></Entry>")


def init_cmd(index: str, data: str, transition: str = "PS", mark: bool = False) -> str:
    return (f"<Mailbox><CoE SdoInfo=\"1\" PdoAssign=\"1\">\n{MARK if mark else ''}<InitCmd>"
            f"<Transition>{transition}</Transition><Index>{index}</Index><SubIndex>0</SubIndex>"
            f"<Data>{data}</Data></InitCmd>\n</CoE></Mailbox>")


def soe_mailbox(init_cmds: str, attributes: str = "") -> str:
    """A drive's mailbox with CoE and SoE (Mailbox/SoE/InitCmd, ETG.2000)."""
    return (f"<Mailbox><CoE SdoInfo=\"1\" PdoAssign=\"1\"/>\n<SoE {attributes}>\n{init_cmds}"
            "\n</SoE></Mailbox>")


def opmode(aa: str, cycle: str = '<CycleTimeSync0 Factor="1">0</CycleTimeSync0>',
           shift: str = "0", name: str = "DC", mark: bool = False, extra: str = "") -> str:
    return (f"{MARK if mark else ''}<OpMode><Name>{name}</Name><Desc>d</Desc>"
            f"<AssignActivate>{aa}</AssignActivate>{cycle}<ShiftTimeSync0>{shift}"
            f"</ShiftTimeSync0>{extra}</OpMode>")


def ident_list_profile(access: str) -> str:
    """PROFILE with a configured module ident list 0xF030 (count and one module), every
    subindex of access ``access``."""
    return PROFILE.replace("</DataTypes>", (
        "<DataType><Name>UDINT</Name><BitSize>32</BitSize></DataType>\n"
        "<DataType><Name>DTF030</Name><BitSize>48</BitSize>"
        "<SubItem><SubIdx>0</SubIdx><Name>Count</Name><Type>USINT</Type><BitSize>8</BitSize>"
        f"<BitOffs>0</BitOffs><Flags><Access>{access}</Access></Flags></SubItem>"
        "<SubItem><SubIdx>1</SubIdx><Name>Module 1</Name><Type>UDINT</Type><BitSize>32"
        f"</BitSize><BitOffs>16</BitOffs><Flags><Access>{access}</Access></Flags></SubItem>"
        "</DataType>\n</DataTypes>")).replace("</Objects>", (
            "<Object><Index>#xF030</Index><Name>Configured module ident list</Name>"
            "<Type>DTF030</Type><BitSize>48</BitSize></Object>\n</Objects>"))


def group_module() -> str:
    """A module with one TxPdo whose entry moves by its slot group (ETG.2000
    Index@DependOnSlotGroup)."""
    return ('<Module><Type ModuleIdent="#x100">Axis</Type><Name>Axis</Name><TxPdo Sm="3">'
            '<Index DependOnSlot="1">#x1A01</Index><Name>Axis inputs</Name><Entry>'
            '<Index DependOnSlotGroup="1">#x5841</Index><SubIndex>0</SubIndex><BitLen>16'
            '</BitLen><Name>Statusword</Name><DataType>UINT</DataType></Entry></TxPdo>'
            '</Module>')


def grouped_slots(group_data: str) -> str:
    return ('<Slots SlotGroupIndexIncrement="#x800">\n<Slot SlotGroup="1" MinInstances="0" '
            'MaxInstances="1"><Name>Slot 1</Name><ModuleIdent>#x100</ModuleIdent></Slot>\n'
            f"{group_data}</Slots>")


def ident_list_slots(mark: bool = False) -> str:
    return (MARK if mark else "") + slots("<ModuleIdent>#x100</ModuleIdent>").replace(
        "<Slots>", '<Slots DownloadModuleIdentList="true">')


@dataclass(frozen=True)
class Case:
    rule: str
    failing: str            # a whole file; the line to report carries MARK
    passing: str            # the nearest correct variant
    files: tuple[tuple[str, str], ...] = ()   # extra files beside it (name, text)


M = MARK
CASES: list[Case] = [
    Case("ESI001", esi().replace("</Devices>", f"{M}</Wrong>"), esi()),
    Case("ESI002", esi(drive(product="12h").replace("<Type ", f"{M}<Type ")),
         esi(drive(product="#x12"))),
    Case("ESI003", esi(drive(eeprom=f"{M}<Eeprom><ByteSize>2048</ByteSize>"
                                    "<ConfigData>080E0</ConfigData></Eeprom>")),
         esi(drive(eeprom="<Eeprom><ByteSize>2048</ByteSize><ConfigData>080E</ConfigData>"
                          "</Eeprom>"))),
    Case("ESI004", esi(drive(), drive(type_name="FX1-B").replace("<Device", f"{M}<Device")),
         esi(drive(), drive(type_name="FX1-B", revision="#x2"))),
    # Across files (a second file with the same identity beside it): the same description,
    # with another name; a different one, with another output entry.
    Case("ESI007", esi(drive().replace("<Device", f"{M}<Device")), esi(drive(revision="#x2")),
         files=(("other/FX1.xml", esi(drive(names='<Name LcId="1033">FX1, another download'
                                                   '</Name>'))),)),
    Case("ESI008", esi(drive().replace("<Device", f"{M}<Device")), esi(drive(revision="#x2")),
         files=(("other/FX1.xml", esi(drive(rx=rx(entry=entry("#x7000", 1, 8, "USINT"))))),)),
    Case("ESI005", esi(drive(names='<Name LcId="1031">FX1 Antrieb</Name>').replace(
        "<Device", f"{M}<Device")),
         esi(drive(names='<Name LcId="1031">FX1 Antrieb</Name><Name>FX1 drive</Name>'))),
    Case("ESI006", esi(drive(eeprom=EEPROM + f"\n{M}<Firmware>1.0</Firmware>")), esi()),

    Case("ESI101", esi(drive(rx=M + rx("#x1800"))), esi(drive(rx=rx("#x17FF")))),
    Case("ESI102", esi(drive(rx=rx() + "\n" + M + rx(attrs='Sm="2"'))),
         esi(drive(rx=rx() + "\n" + rx("#x1601", attrs='Sm="2"')))),
    Case("ESI103", esi(drive(rx=rx(entry=entry("#x7001", 0, 16, "UINT", True)))), esi()),
    Case("ESI104", esi(drive(rx=rx(entry=entry("#x7010", 2, 32, "DINT", True)))),
         esi(drive(rx=rx(entry=entry("#x7010", 1, 32, "DINT"))))),
    Case("ESI105", esi(drive(rx=rx(entry=entry("#x7000", 0, 32, "UDINT", True)))), esi()),
    Case("ESI106", esi(drive(rx=rx(entry=entry("#x7010", 1, 16, "INT", True)))),
         esi(drive(rx=rx(entry=entry("#x7010", 1, 32, "DINT"))))),
    Case("ESI107", esi(drive(rx=rx(entry=entry("#x7000", 0, 16, "INT", True)))),
         esi(drive(rx=rx(entry=entry("#x7000", 0, 16, "UINT16"))))),
    Case("ESI108", esi(drive(rx=M + rx(attrs='Mandatory="1" Sm="7"'))), esi()),
    Case("ESI109", esi(drive(rx=M + rx(attrs='Mandatory="1" Sm="3"'))), esi()),
    Case("ESI110", esi(drive(rx=M + rx(extra="<Exclude>#x1605</Exclude>"))),
         esi(drive(rx=rx(extra="<Exclude>#x1601</Exclude>") + "\n"
                   + rx("#x1601", attrs="", extra="<Exclude>#x1600</Exclude>")))),
    Case("ESI111", esi(drive(rx=M + rx() + "\n"
                             + rx("#x1601", attrs='Mandatory="1"',
                                  extra="<Exclude>#x1600</Exclude>"))),
         esi(drive(rx=rx() + "\n" + rx("#x1601", attrs="", extra="<Exclude>#x1600</Exclude>")))),
    Case("ESI112", esi(drive(sm2=M + SM2.replace("<Sm ", '<Sm MaxSize="1" ')),),
         esi(drive(sm2=SM2.replace("<Sm ", '<Sm MaxSize="2" ')))),
    Case("ESI113", esi(drive(rx=rx(entry=f"{M}<Entry><Index>0</Index><BitLen>256</BitLen></Entry>"))),
         esi(drive(rx=rx(entry="<Entry><Index>0</Index><BitLen>255</BitLen></Entry>")))),
    # The Ref/Chn form of old Beckhoff files (EL3142 in "Beckhoff EtherCAT Terminals.xml").
    Case("ESI114", esi(drive(tx=f'{M}<TxPdo Mandatory="1" Sm="3"><Name>In</Name></TxPdo>')),
         esi()),

    Case("ESI201", esi(drive(sm3=M + SM3.replace("#x1180", "#x1101"))), esi()),
    Case("ESI202", esi(drive(sm2=M + SM2, sm3=SM3.replace("#x1180", "#x1104"))),
         esi(drive(sm3=SM3.replace("#x1180", "#x1106")))),
    Case("ESI203", esi(drive(sm2=M + SM2.replace("#x1100", "#x0800"))),
         esi(drive(sm2=SM2.replace("#x1100", "#xFF00")))),
    Case("ESI204", esi(drive(sm0=M + SM0.replace('DefaultSize="128"', 'DefaultSize="12"'))),
         esi(drive(sm0=SM0.replace('DefaultSize="128"', 'DefaultSize="16"')))),
    Case("ESI205", esi(drive(sm0=M + SM0.replace("#x26", "#x22"))), esi()),
    Case("ESI206", esi(drive(sm3=M + SM3.replace("#x20", "#x22"))), esi()),
    Case("ESI207", esi(drive(sm2=M + SM2.replace("#x64", "#x60"))), esi()),
    Case("ESI208", esi(drive(sm0="", sm1="", sm2=SM2.replace("#x1100", "#x1000"),
                             sm3=SM3.replace("#x1180", "#x1080"),
                             rx=rx(attrs='Mandatory="1" Sm="0"'),
                             tx=TXPDO.replace('Sm="3"', 'Sm="1"'),
                             mailbox=M + MAILBOX)), esi()),
    Case("ESI209", esi(drive(fmmus=f"{M}<Fmmu>Inputs</Fmmu>\n<Fmmu>MBoxState</Fmmu>")), esi()),
    Case("ESI210", esi(drive(fmmus="").replace("<Device", f"{M}<Device")), esi()),
    Case("ESI211", esi(drive(fmmus=FMMUS + "\n<Fmmu>Outputs</Fmmu>" * 13
                             + f"\n{M}<Fmmu>Inputs</Fmmu>")),
         esi(drive(fmmus=FMMUS + "\n<Fmmu>Outputs</Fmmu>" * 13))),
    Case("ESI212", esi(drive(sm1=M + SM1.replace('DefaultSize="128"', 'MinSize="128"'))),
         esi(drive(sm1=SM1.replace('DefaultSize="128"', 'MinSize="64" DefaultSize="128"')))),
    Case("ESI213", esi(drive(sm0=M + SM0.replace('DefaultSize="128" ', ''))), esi()),
    Case("ESI214", esi(drive(mailbox=MAILBOX.replace(
        "<Mailbox>", f"<Mailbox><EoE>\n{M}<InitCmd><Transition>IP</Transition><Type>2</Type>"
                     "<Data>0300000002000000000701000000</Data></InitCmd>\n</EoE>"))),
         esi(drive(mailbox=MAILBOX.replace("<Mailbox>", "<Mailbox><EoE IP=\"1\"/>")))),

    Case("ESI215", esi(drive(sm3=M + SM3.replace(">Inputs<", "><"))), esi()),
    Case("ESI216", esi(drive(mailbox=soe_mailbox(
        f"{M}<InitCmd><Transition>PS</Transition><IDN>1</IDN></InitCmd>"))),
         esi(drive(mailbox=soe_mailbox(
             "<InitCmd><Transition>PS</Transition><IDN>1</IDN><Data>d007</Data></InitCmd>")))),
    Case("ESI217", esi(drive(mailbox=soe_mailbox(
        f"{M}<InitCmd Chn=\"2\"><Transition>PS</Transition><IDN>32</IDN><Data>0b00</Data>"
        "</InitCmd>", 'ChannelCount="2"'))),
         esi(drive(mailbox=soe_mailbox(
             "<InitCmd Chn=\"1\"><Transition>PS</Transition><IDN>32</IDN><Data>0b00</Data>"
             "</InitCmd>", 'ChannelCount="2"')))),

    Case("ESI301", esi(drive(mailbox=init_cmd("#x8001", "0100", mark=True))), esi()),
    Case("ESI302", esi(drive(mailbox=init_cmd("#x8000", "0100", "SO", mark=True))),
         esi(drive(mailbox=init_cmd("#x8000", "0100", "IP")))),
    Case("ESI303", esi(drive(rx=rx(entry=entry("#x7000", 0, 16, "UINT17", True)))),
         esi(drive(rx=rx(entry=entry("#x7000", 0, 16, "UNSIGNED16"))))),
    Case("ESI304", esi(drive(mailbox=init_cmd("#x8000", "01000000", mark=True))), esi()),

    Case("ESI401", esi(drive(dc=f"<Dc>{opmode('#x100', mark=True)}</Dc>")),
         esi(drive(dc=f"<Dc>{opmode('#x0')}</Dc>"))),
    Case("ESI402", esi(drive(dc=f"<Dc>{opmode('#x200', mark=True)}</Dc>")), esi()),
    Case("ESI403", esi(drive(dc="<Dc>" + opmode(
        "#x300", "<CycleTimeSync0>1000000</CycleTimeSync0>", "1000000", mark=True) + "</Dc>")),
         esi(drive(dc="<Dc>" + opmode("#x300", "<CycleTimeSync0>1000000</CycleTimeSync0>",
                                      "500000") + "</Dc>"))),
    Case("ESI404", esi(drive(dc=f"<Dc>{opmode('#x300')}\n{opmode('#x700', mark=True)}</Dc>")),
         esi(drive(dc="<Dc>" + opmode(
             "#x300", extra='<VendorSpecific><TwinCAT IgnoreFromBuildNo="1506"/>'
                            "</VendorSpecific>") + "\n" + opmode(
             "#x700", extra='<VendorSpecific><TwinCAT UseFromBuildNo="1506"/>'
                            "</VendorSpecific>") + "</Dc>"))),

    Case("ESI501", esi(drive(eeprom=f"{M}<Eeprom><ByteSize>2048</ByteSize><ConfigData>"
                                    "080E00CC881300000000000000000000</ConfigData></Eeprom>")),
         esi(drive(eeprom="<Eeprom><ByteSize>2048</ByteSize><ConfigData>"
                          "080E00CC8813000000000000AB00</ConfigData></Eeprom>"))),
    Case("ESI502", esi(drive(eeprom=f"{M}<Eeprom><ByteSize>2048</ByteSize>"
                                    "<ConfigData>080E00CC881300</ConfigData></Eeprom>")), esi()),
    Case("ESI503", esi(drive(eeprom=f"{M}<Eeprom><ByteSize>1000</ByteSize>"
                                    "<ConfigData>080E</ConfigData></Eeprom>")),
         esi(drive(eeprom="<Eeprom><ByteSize>1024</ByteSize><ConfigData>080E</ConfigData>"
                          "</Eeprom>"))),

    Case("ESI601", esi(drive(slots=M + slots("<ModuleIdent>#x200</ModuleIdent>")),
                       modules=module("#x100")),
         esi(drive(slots=slots("<ModuleIdent>#x100</ModuleIdent>")), modules=module("#x100"))),
    Case("ESI602", esi(drive(slots=slots("<ModuleIdent>#x300</ModuleIdent>")),
                       head=f"{M}<InfoReference>Libs\\Missing.xml</InfoReference>\n"),
         esi(drive(slots=slots("<ModuleIdent>#x300</ModuleIdent>")),
             head="<InfoReference>Libs\\Modules.xml</InfoReference>\n"),
         files=(("Libs/Modules.xml",
                 '<?xml version="1.0"?>\n<EtherCATModule Version="1.12"><Vendor><Id>#xE0F1</Id>'
                 "<Name>Fixture Vendor</Name></Vendor><Modules>" + module("#x300")
                 + "</Modules></EtherCATModule>\n"),)),
    Case("ESI603", esi(drive(), modules=module("#x100") + "\n" + M + module("#x100", "N")),
         esi(drive(), modules=module("#x100") + "\n" + module("#x101", "N"))),
    # A module whose entry moves by its slot group (an axis of a multi-axis drive), in a
    # slot of no group; the same slot in group 1 is fine.
    Case("ESI604", esi(drive(slots=f'<Slots>\n{M}<Slot MinInstances="0" MaxInstances="1">'
                                   '<Name>Slot 1</Name><ModuleIdent>#x100</ModuleIdent></Slot>'
                                   '</Slots>'), modules=group_module()),
         esi(drive(slots='<Slots>\n<Slot SlotGroup="1" MinInstances="0" MaxInstances="1">'
                         '<Name>Slot 1</Name><ModuleIdent>#x100</ModuleIdent></Slot>'
                         '</Slots>'), modules=group_module())),
    Case("ESI605", esi(drive(profile=ident_list_profile("ro"), slots=ident_list_slots(True)),
                       modules=module("#x100")),
         esi(drive(profile=ident_list_profile("rw"), slots=ident_list_slots()),
             modules=module("#x100"))),
    # Slot group 1 described twice (the second is marked); once is fine.
    Case("ESI606", esi(drive(slots=grouped_slots(
        '<SlotGroupData SlotGroup="1"><Name>Axis A</Name></SlotGroupData>\n'
        f'{M}<SlotGroupData SlotGroup="1"><Name>Axis B</Name></SlotGroupData>')),
        modules=group_module()),
         esi(drive(slots=grouped_slots('<SlotGroupData SlotGroup="1"><Name>Axis A</Name>'
                                       '</SlotGroupData>')), modules=group_module())),
]


def marked_line(text: str) -> int:
    """The 1-based line of the MARK comment."""
    return text[:text.index(MARK)].count("\n") + 1
