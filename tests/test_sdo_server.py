"""The SDO client (master side) against the SDO server of an emulated slave, in memory: every
transfer kind, complete access, the abort codes, AL-state rules and the process-data sizes
an ESC derives from the object dictionary; then real devices from the corpus."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from ecatcfg.esc import AlState
from ecatcfg.esi import Library
from ecatcfg.esi.coe import has_coe
from ecatcfg.esi.reader import read_bytes
from ecatcfg.runtime import mailbox as mbx
from ecatcfg.runtime.mailbox import (
    Abort, DownloadSegmentResponse, MailboxCounter, MailboxError, MailboxProtocolError,
    MbxErrorDetail, MbxType, SdoAbort, SdoInfo, UploadResponse, UploadSegment, decode,
    pad_to,
)
from ecatcfg.runtime.segment.od_entries import OdEntry, OdObject
from ecatcfg.runtime.segment.objects import ObjectDictionary
from ecatcfg.runtime.master.sdo_client import SdoDownload, SdoUpload
from ecatcfg.runtime.segment.mailbox_server import MailboxServer
from ecatcfg.runtime.segment.sdo_server import SdoServer
from conftest import device_xml, esi_xml

PREOP, SAFEOP, OP = AlState.PREOP, AlState.SAFEOP, AlState.OP


def sub(n: int, name: str, type_: str, bits: int, offs: int, access: str = "rw",
        mapping: str = "") -> str:
    pdo = f"<PdoMapping>{mapping}</PdoMapping>" if mapping else ""
    return (f"<SubItem><SubIdx>{n}</SubIdx><Name>{name}</Name><Type>{type_}</Type>"
            f"<BitSize>{bits}</BitSize><BitOffs>{offs}</BitOffs>"
            f"<Flags><Access>{access}</Access>{pdo}</Flags></SubItem>")


def obj(index: int, name: str, type_: str, bits: int, info: str = "", access: str = "rw",
        extra: str = "") -> str:
    return (f"<Object><Index>#x{index:04X}</Index><Name>{name}</Name><Type>{type_}</Type>"
            f"<BitSize>{bits}</BitSize>{info}<Flags><Access{extra}>{access}</Access>"
            f"</Flags></Object>")


def entry(index: int, subindex: int, bits: int, type_: str = "UINT") -> str:
    return (f"<Entry><Index>#x{index:04X}</Index><SubIndex>{subindex}</SubIndex>"
            f"<BitLen>{bits}</BitLen><Name>e</Name><DataType>{type_}</DataType></Entry>")


SI0 = sub(0, "SubIndex 000", "USINT", 8, 0, "ro")
BODY = f"""
<Profile><ProfileNo>5001</ProfileNo><AddInfo>7</AddInfo><Dictionary>
  <DataTypes>
    <DataType><Name>DT6000</Name><BitSize>40</BitSize>{SI0}
      {sub(1, "Button", "BOOL", 1, 16, "ro", "T")}{sub(2, "Counter", "UINT", 16, 24, "ro", "T")}
    </DataType>
    <DataType><Name>DT7000</Name><BitSize>40</BitSize>{SI0}
      {sub(1, "Setpoint", "UINT", 16, 16, "rw", "R")}{sub(2, "Mode", "USINT", 8, 32, "rw", "R")}
    </DataType>
    <DataType><Name>DT2008</Name><BitSize>40</BitSize>{sub(0, "SubIndex 000", "USINT", 8, 0)}
      {sub(1, "Flag", "BOOL", 1, 16)}{sub(2, "Level", "BIT3", 3, 17)}
      {sub(3, "Word", "UINT", 16, 24)}
    </DataType>
  </DataTypes>
  <Objects>
    {obj(0x1008, "Device name", "STRING(20)", 160,
         "<Info><DefaultString>ecatcfg test device</DefaultString></Info>", "ro")}
    {obj(0x2000, "Long text", "STRING(300)", 2400,
         "<Info><DefaultString>hello</DefaultString></Info>")}
    {obj(0x2001, "Limited", "UDINT", 32,
         "<Info><DefaultValue>100</DefaultValue><MinValue>10</MinValue>"
         "<MaxValue>1000</MaxValue></Info>")}
    {obj(0x2002, "Password", "UINT", 16, "", "wo")}
    {obj(0x2003, "Constant", "SINT", 8, "<Info><DefaultValue>-5</DefaultValue></Info>", "ro")}
    {obj(0x2004, "Switch", "BOOL", 1)}
    {obj(0x2005, "PreOp only", "DINT", 32, "", "rw", ' WriteRestrictions="PreOp"')}
    {obj(0x2006, "Signed", "INT", 16,
         "<Info><DefaultValue>-7</DefaultValue><MinValue>#xFF9C</MinValue>"
         "<MaxValue>100</MaxValue></Info>")}
    {obj(0x2007, "Not mappable", "UDINT", 32)}
    <Object><Index>#x2008</Index><Name>Bits</Name><Type>DT2008</Type><BitSize>40</BitSize>
      <Info><SubItem><Name>SubIndex 000</Name><Info><DefaultValue>3</DefaultValue></Info>
      </SubItem><SubItem><Name>Flag</Name><Info><DefaultValue>1</DefaultValue></Info></SubItem>
      <SubItem><Name>Level</Name><Info><DefaultValue>5</DefaultValue></Info></SubItem>
      <SubItem><Name>Word</Name><Info><DefaultData>3412</DefaultData></Info></SubItem></Info>
    </Object>
    <Object><Index>#x6000</Index><Name>Inputs</Name><Type>DT6000</Type><BitSize>40</BitSize>
    </Object>
    <Object><Index>#x7000</Index><Name>Outputs</Name><Type>DT7000</Type><BitSize>40</BitSize>
    </Object>
    {obj(0x7010, "Output word", "UDINT", 32)}
  </Objects>
</Dictionary></Profile>
<Fmmu>Outputs</Fmmu><Fmmu>Inputs</Fmmu>
<Sm ControlByte="#x26" DefaultSize="128" Enable="1" StartAddress="#x1000">MBoxOut</Sm>
<Sm ControlByte="#x22" DefaultSize="128" Enable="1" StartAddress="#x1080">MBoxIn</Sm>
<Sm ControlByte="#x64" Enable="1" StartAddress="#x1100">Outputs</Sm>
<Sm ControlByte="#x20" Enable="1" StartAddress="#x1180">Inputs</Sm>
<RxPdo Sm="2"><Index>#x1600</Index><Name>Out</Name>{entry(0x7000, 1, 16)}
  {entry(0x7000, 2, 8, "USINT")}</RxPdo>
<RxPdo><Index>#x1601</Index><Name>Out 2</Name>{entry(0x7010, 0, 32, "UDINT")}</RxPdo>
<TxPdo Fixed="1" Sm="3"><Index>#x1A00</Index><Name>In</Name>{entry(0x6000, 1, 1, "BOOL")}
  <Entry><Index>0</Index><BitLen>7</BitLen></Entry>{entry(0x6000, 2, 16)}</TxPdo>
<Mailbox><CoE SdoInfo="1" PdoAssign="1" PdoConfig="1" CompleteAccess="1"/></Mailbox>
"""


def fixture_device():
    esi = read_bytes(esi_xml(device_xml(body=BODY)).encode(), "fixture.xml")
    assert [p for p in esi.problems if p.severity == "error"] == []
    return esi.devices[0]


class Slave:
    """An object dictionary, its SDO server behind the slave's mailbox, and the master's side
    of the mailbox."""

    def __init__(self, od: ObjectDictionary, sm0: int = 128, sm1: int = 128) -> None:
        self.od = od
        self.server = MailboxServer(sm0, sm1, coe=SdoServer(od, sm0, sm1))
        self.sm0 = sm0
        self.sm1 = sm1
        self.counter = MailboxCounter()      # the master's counter for this slave
        self.exchanges = 0

    def run(self, txn, state: AlState = PREOP):
        request = txn.first_request()
        while request is not None:
            assert len(request) == self.sm0
            replies = self.server.handle(request, state)
            assert len(replies) == 1 and len(replies[0]) == self.sm1
            self.exchanges += 1
            request = txn.on_response(replies[0])
        assert txn.done
        return txn

    def upload(self, index: int, subindex: int, ca: bool = False,
               state: AlState = PREOP) -> bytes:
        return self.run(SdoUpload(index, subindex, ca, self.sm0, self.counter), state).result

    def download(self, index: int, subindex: int, data: bytes, ca: bool = False,
                 state: AlState = PREOP) -> None:
        self.run(SdoDownload(index, subindex, data, ca, self.sm0, self.counter), state)

    def raw(self, msg: bytes, state: AlState = PREOP) -> list:
        return [decode(r) for r in self.server.handle(pad_to(msg, self.sm0), state)]


@pytest.fixture
def slave() -> Slave:
    return Slave(ObjectDictionary.from_device(fixture_device()))


def u32(value: int) -> bytes:
    return struct.pack("<I", value)


# -- the dictionary built from the ESI ------------------------------------------------------

def test_objects_a_master_needs_exist(slave):
    od = slave.od
    assert od.int_value(0x1000) == 7 << 16 | 5001          # AddInfo << 16 | ProfileNo
    assert [od.int_value(0x1018, s) for s in range(5)] == [4, 0xE0F1, 0x10, 0x1, 0]
    assert [od.int_value(0x1C00, s) for s in range(5)] == [4, 1, 2, 3, 4]
    assert [od.int_value(0x1C12, s) for s in range(3)] == [1, 0x1600, 0]
    assert [od.int_value(0x1C13, s) for s in range(2)] == [1, 0x1A00]
    assert [od.int_value(0x1600, s) for s in range(3)] == [2, 0x70000110, 0x70000208]
    assert [od.int_value(0x1A00, s) for s in range(4)] == [3, 0x60000101, 0x00000007,
                                                          0x60000210]
    assert od.int_value(0x1601, 1) == 0x70100020
    assert od.value(0x1008) == b"ecatcfg test device\0"
    assert od.int_value(0x2003) == -5
    assert od.value(0x2006) == b"\xf9\xff" and od.int_value(0x2006) == -7


def test_default_process_data_sizes(slave):
    assert slave.od.sm_bits(2) == 24
    assert slave.od.sm_bits(3) == 24                       # 1 + 7-bit gap + 16
    assert slave.od.rx_entries(2) == [(0x7000, 1, 16), (0x7000, 2, 8)]
    assert slave.od.tx_entries(3) == [(0x6000, 1, 1), (0, 0, 7), (0x6000, 2, 16)]
    assert slave.od.sm_bits(0) is None                     # mailbox SM: no assignment


def test_dictionary_less_device_gets_its_communication_objects():
    body = ('<Sm ControlByte="#x26" DefaultSize="128" StartAddress="#x1000">MBoxOut</Sm>'
            '<Sm ControlByte="#x22" DefaultSize="128" StartAddress="#x1080">MBoxIn</Sm>'
            '<Sm ControlByte="#x64" StartAddress="#x1100">Outputs</Sm>'
            '<Sm ControlByte="#x20" StartAddress="#x1180">Inputs</Sm>'
            f'<RxPdo Sm="2"><Index>#x1600</Index><Name>O</Name>{entry(0x7000, 1, 8, "USINT")}'
            f'</RxPdo><TxPdo Sm="3"><Index>#x1A00</Index><Name>I</Name>'
            f'{entry(0x6000, 1, 16)}{entry(0x6000, 2, 32, "UDINT")}</TxPdo>'
            '<Mailbox><CoE/></Mailbox>')
    dev = read_bytes(esi_xml(device_xml(body=body)).encode(), "bare.xml").devices[0]
    od = ObjectDictionary.from_device(dev)
    assert od.sm_bits(2) == 8 and od.sm_bits(3) == 48
    assert od.int_value(0x6000, 0) == 2 and od[0x6000][2].mappable == "T"
    s = Slave(od)
    assert s.upload(0x1018, 2) == u32(0x10)
    with pytest.raises(SdoAbort) as err:               # no PdoAssign: read-only
        s.download(0x1C12, 0, b"\0")
    assert err.value.code == 0x06010002


# -- transfers ------------------------------------------------------------------------------

def test_expedited_upload_and_download(slave):
    assert slave.upload(0x2001, 0) == u32(100)
    slave.download(0x2001, 0, u32(500))
    assert slave.upload(0x2001, 0) == u32(500)
    assert slave.exchanges == 3
    # On the wire: 0x4F-style expedited response with the data at +6.
    (header, msg), = slave.raw(mbx.encode_upload_request(0x1018, 1, slave.counter()))
    assert header.type == MbxType.COE and header.address == 0
    assert msg == UploadResponse(0x1018, 1, u32(0xE0F1), 4, True, False)


def test_an_expedited_download_is_answered_with_its_data_echoed(slave):
    """Real Beckhoff firmware echoes the request's 4 data bytes in the reserved bytes of
    the response (ETG.1000.6): the EL3004 of ethercrab-rs/ethercrab
    tests/replay-ek1914-el3004-configure.pcapng answers 0x1C13:01 = 0x1A00 (request
    ``2b 13 1c 01 00 1a 00 00``) with ``60 13 1c 01 00 1a 00 00``.  The same request here;
    an abort keeps its code there."""
    slave.download(0x1C13, 0, b"\0")                    # unassign to change sub 1
    def sent(sdo: str) -> bytes:               # mailbox header with the next counter, CoE
        header = bytes.fromhex("0a00 0000 00") + bytes((slave.counter() << 4 | MbxType.COE,))
        [reply] = slave.server.handle(pad_to(header + bytes.fromhex("0020" + sdo),
                                             slave.sm0), PREOP)
        return reply[6:16]

    assert sent("2b13 1c01 001a 0000") == bytes.fromhex("0030 6013 1c01 001a 0000")
    assert sent("2b34 1201 0100 0000") == bytes.fromhex("0020 8034 1201 0000 0206")


def test_normal_upload_in_one_message(slave):
    assert slave.upload(0x1008, 0) == b"ecatcfg test device\0"
    assert slave.exchanges == 1


def test_segmented_upload_larger_than_the_mailbox(slave):
    text = slave.upload(0x2000, 0)
    assert text == b"hello".ljust(300, b"\0")
    # 128-byte SM1: 112 bytes in the initiate response, then 119 + 69 in two segments.
    assert slave.exchanges == 3


def test_upload_segments_on_the_wire(slave):
    slave.od.set_value(0x2000, 0, bytes(range(256)) + bytes(44))
    (_, first), = slave.raw(mbx.encode_upload_request(0x2000, 0, slave.counter()))
    assert first.size == 300 and len(first.data) == 128 - 16 and not first.expedited
    (_, seg1), = slave.raw(mbx.encode_upload_segment_request(False, slave.counter()))
    (_, seg2), = slave.raw(mbx.encode_upload_segment_request(True, slave.counter()))
    assert seg1 == UploadSegment(bytes(range(112, 231)), False, False)     # SM1 - 9 = 119
    assert seg2 == UploadSegment((bytes(range(231, 256)) + bytes(44)), True, True)


def test_segmented_download_with_a_small_mailbox():
    s = Slave(ObjectDictionary.from_device(fixture_device()), sm0=64, sm1=64)
    text = bytes(range(1, 201)) + b"x" * 100
    s.download(0x2000, 0, text)
    # 48 bytes in the initiate (SM0 - 16), then 55 per segment (SM0 - 9): 5 segments.
    assert s.exchanges == 1 + 5
    assert s.od.value(0x2000) == text
    assert s.upload(0x2000, 0) == text


def test_a_200_byte_domain_up_and_down(slave):
    blob = OdObject(0x3000, "Blob", variable=True)
    blob.add(OdEntry(0, "Blob", "DOMAIN", 0, bytes(range(200))))
    slave.od.add(blob)
    assert slave.upload(0x3000, 0) == bytes(range(200))
    assert slave.exchanges == 2                      # 112 + one segment of 88
    slave.download(0x3000, 0, b"\xAA" * 250)         # a domain takes any length
    assert slave.upload(0x3000, 0) == b"\xAA" * 250
    with pytest.raises(SdoAbort) as err:
        slave.upload(0x3000, 0, ca=True)
    assert err.value.code == 0x06010004


def test_short_string_write_and_empty_string(slave):
    slave.download(0x2000, 0, b"hi there")
    assert slave.od.value(0x2000) == b"hi there".ljust(300, b"\0")
    with pytest.raises(SdoAbort) as err:
        slave.download(0x2000, 0, b"")
    assert err.value.code == 0x06070013


# -- complete access ------------------------------------------------------------------------

def test_complete_access_read_and_write_of_the_pdo_assignment(slave):
    assert slave.upload(0x1C12, 0, ca=True) == bytes.fromhex("01000016")
    assert slave.upload(0x1C13, 0, ca=True) == bytes.fromhex("0100001a")
    # As an ENI writes it (docs/eni-exports.md §5): count 2 + pad, then 0x1600, 0x1601.
    slave.download(0x1C12, 0, bytes.fromhex("020000160116"), ca=True)
    assert slave.upload(0x1C12, 0, ca=True) == bytes.fromhex("020000160116")
    assert slave.upload(0x1C12, 1, ca=True) == bytes.fromhex("00160116")
    assert slave.od.sm_bits(2) == 24 + 32
    assert slave.od.rx_entries(2)[-1] == (0x7010, 0, 32)
    slave.download(0x1C12, 0, bytes.fromhex("0000"), ca=True)      # clear: SI0 + pad only
    assert slave.upload(0x1C12, 0, ca=True) == bytes.fromhex("0000")
    assert slave.od.sm_bits(2) == 0 and slave.od.int_value(0x1C12, 1) == 0x1600
    with pytest.raises(SdoAbort) as err:
        slave.download(0x1C12, 0, bytes.fromhex("020000160116"), ca=True, state=SAFEOP)
    assert err.value.code == 0x08000022


def test_complete_access_of_a_mapping_object(slave):
    assert slave.upload(0x1A00, 0, ca=True) == bytes.fromhex("0300" "01010060" "07000000"
                                                             "10020060")
    slave.download(0x1600, 0, bytes.fromhex("0100" "20001070"), ca=True)
    assert [slave.od.int_value(0x1600, s) for s in range(2)] == [1, 0x70100020]
    assert slave.od.sm_bits(2) == 32
    with pytest.raises(SdoAbort) as err:                 # fixed PDO: read-only
        slave.download(0x1A00, 0, bytes.fromhex("0000"), ca=True)
    assert err.value.code == 0x06010002


def test_complete_access_packs_bit_entries(slave):
    # SI0 as 1 byte + pad, BOOL and BIT3 packed into one byte, UINT on the next byte.
    assert slave.upload(0x2008, 0, ca=True) == bytes.fromhex("0300" "0b" "3412")
    slave.download(0x2008, 0, bytes.fromhex("0300" "06" "7856"), ca=True)
    assert [slave.od.int_value(0x2008, s) for s in range(4)] == [3, 0, 3, 0x5678]
    assert slave.upload(0x2008, 1, ca=True) == bytes.fromhex("06" "7856")


# -- abort codes, each provoked ---------------------------------------------------------------

ABORTS = [
    ("upload", 0x5555, 0, None, False, PREOP, 0x06020000),
    ("upload", 0x1018, 9, None, False, PREOP, 0x06090011),
    ("download", 0x2003, 0, b"\x01", False, PREOP, 0x06010002),
    ("upload", 0x2002, 0, None, False, PREOP, 0x06010001),
    ("download", 0x2001, 0, b"\x01\x00", False, PREOP, 0x06070010),
    ("download", 0x2000, 0, b"x" * 301, False, PREOP, 0x06070012),
    ("download", 0x2000, 0, b"", False, PREOP, 0x06070013),
    ("download", 0x1C12, 0, b"\x00", False, SAFEOP, 0x08000022),
    ("download", 0x2005, 0, u32(1), False, OP, 0x08000022),
    ("download", 0x2004, 0, b"\x02", False, PREOP, 0x06090030),
    ("download", 0x2001, 0, u32(2000), False, PREOP, 0x06090031),
    ("download", 0x2001, 0, u32(5), False, PREOP, 0x06090032),
    ("download", 0x2006, 0, struct.pack("<h", -101), False, PREOP, 0x06090032),
    ("download", 0x1C12, 0, b"\x05", False, PREOP, 0x06090031),     # more than 2 slots
    ("download", 0x1C12, 1, b"\x01\x16", False, PREOP, 0x06010003),
    ("download", 0x1600, 2, u32(0x70100020), False, PREOP, 0x06010003),
    ("upload", 0x1018, 2, None, True, PREOP, 0x06010000),
    ("upload", 0x2000, 0, None, True, PREOP, 0x06010004),
    ("download", 0x2008, 0, bytes(6), True, PREOP, 0x06070012),
    ("download", 0x2008, 0, bytes(4), True, PREOP, 0x06070010),     # ends inside the UINT
]


@pytest.mark.parametrize("kind,index,subindex,data,ca,state,code", ABORTS,
                         ids=[f"{a[0]}-{a[1]:04x}:{a[2]}-{a[6]:08x}" for a in ABORTS])
def test_abort(slave, kind, index, subindex, data, ca, state, code):
    with pytest.raises(SdoAbort) as err:
        if kind == "upload":
            slave.upload(index, subindex, ca, state)
        else:
            slave.download(index, subindex, data, ca, state)
    assert err.value.code == code
    assert f"0x{code:08X} ({mbx.ABORT_CODES[code]})" in str(err.value)


def test_writes_accepted_within_the_limits(slave):
    slave.download(0x2006, 0, struct.pack("<h", -100))      # #xFF9C read as -100
    slave.download(0x2005, 0, u32(7), state=PREOP)
    slave.download(0x2004, 0, b"\x01")
    assert slave.upload(0x2005, 0, state=OP) == u32(7)       # reads are not restricted


def test_toggle_bit_errors_abort_the_transfer(slave):
    text = b"y" * 200
    (_, resp), = slave.raw(mbx.encode_download_normal(0x2000, 0, 300, text[:112],
                                                      slave.counter()))
    assert resp == mbx.DownloadResponse(0x2000, 0, False)
    (_, abort), = slave.raw(mbx.encode_download_segment(text[112:], True, False,
                                                        slave.counter()))
    assert abort == Abort(0x2000, 0, 0x05030000)
    # The transfer is over: a further segment has no transfer to belong to.
    (_, abort), = slave.raw(mbx.encode_download_segment(b"z", False, True, slave.counter()))
    assert abort == Abort(0, 0, 0x05040001)
    # Upload: the first segment request must carry toggle 0.
    slave.raw(mbx.encode_upload_request(0x2000, 0, slave.counter()))
    (_, abort), = slave.raw(mbx.encode_upload_segment_request(True, slave.counter()))
    assert abort == Abort(0x2000, 0, 0x05030000)


def test_download_segments_echo_the_toggle(slave):
    slave.raw(mbx.encode_download_normal(0x2000, 0, 300, b"a" * 112, slave.counter()))
    replies = [slave.raw(mbx.encode_download_segment(b"b" * 94, t, last, slave.counter()))[0][1]
               for t, last in ((False, False), (True, True))]
    assert replies == [DownloadSegmentResponse(False), DownloadSegmentResponse(True)]
    assert slave.od.value(0x2000) == b"a" * 112 + b"b" * 188


def test_wrong_size_is_refused_at_the_initiate(slave):
    # Segments would follow; the announced size already tells the object cannot take it.
    for index, size, code in ((0x2000, 301, 0x06070012), (0x2001, 200, 0x06070010),
                              (0x2003, 200, 0x06010002)):
        (_, reply), = slave.raw(mbx.encode_download_normal(index, 0, size, b"q" * 112,
                                                           slave.counter()))
        assert reply == Abort(index, 0, code)
    (_, reply), = slave.raw(mbx.encode_download_normal(0x1C12, 0, 200, b"q" * 112,
                                                       slave.counter(), complete_access=True))
    assert reply == Abort(0x1C12, 0, 0x06070012)


def test_unknown_command_specifier(slave):
    (_, abort), = slave.raw(bytes.fromhex("0a00 0000 00 13 0020 C0 0010 00 00000000"
                                          .replace(" ", "")))
    assert abort == Abort(0x1000, 0, 0x05040001)


def test_master_abort_ends_a_transfer_silently(slave):
    slave.raw(mbx.encode_upload_request(0x2000, 0, slave.counter()))
    assert slave.raw(mbx.encode_abort(0x2000, 0, 0x05040000, slave.counter())) == []
    (_, abort), = slave.raw(mbx.encode_upload_segment_request(False, slave.counter()))
    assert abort.code == 0x05040001


def test_injected_faults(slave):
    slave.od.inject_abort(0x2001, 0, 0x06060000)
    for action in (lambda: slave.upload(0x2001, 0), lambda: slave.download(0x2001, 0, u32(1))):
        with pytest.raises(SdoAbort) as err:
            action()
        assert err.value.code == 0x06060000
        assert "access failed due to a hardware error" in str(err.value)
    slave.od.inject_abort(0x1C12, 1, 0x08000020)
    with pytest.raises(SdoAbort) as err:                     # complete access covers :01
        slave.upload(0x1C12, 0, ca=True)
    assert err.value.code == 0x08000020
    slave.od.inject_abort(0x2001, 0, None)
    assert slave.upload(0x2001, 0) == u32(100)


# -- AL state rules and the process-data size -------------------------------------------------

def test_pdo_assignment_is_writable_in_preop_only(slave):
    for state in (SAFEOP, OP):
        with pytest.raises(SdoAbort) as err:
            slave.download(0x1C12, 0, b"\x00", state=state)
        assert err.value.code == 0x08000022
    slave.download(0x1C12, 0, b"\x00")
    assert slave.od.sm_bits(2) == 0
    with pytest.raises(SdoAbort) as err:                     # fixed mapping
        slave.download(0x1A00, 0, b"\x00")
    assert err.value.code == 0x06010002


def test_sm_bits_after_reassigning(slave):
    od = slave.od
    # The ENI sequence: clear the count, write the entries, set the count.
    slave.download(0x1C12, 0, b"\x00")
    slave.download(0x1C12, 1, b"\x01\x16")
    slave.download(0x1C12, 0, b"\x01")
    assert od.sm_bits(2) == 32 and od.rx_entries(2) == [(0x7010, 0, 32)]
    slave.download(0x1C12, 0, b"\x00")
    slave.download(0x1C12, 2, b"\x00\x16")
    slave.download(0x1C12, 0, b"\x02")
    assert od.sm_bits(2) == 32 + 24
    # Remap 0x1600 with a padding gap.
    slave.download(0x1600, 0, b"\x00")
    slave.download(0x1600, 1, u32(0x70000110))
    slave.download(0x1600, 2, u32(0x00000008))
    slave.download(0x1600, 0, b"\x02")
    assert od.sm_bits(2) == 32 + 24 and od.rx_entries(2)[-1] == (0, 0, 8)


@pytest.mark.parametrize("assign,mapping", [
    (0x1605, None),                     # the assignment names a missing mapping object
    (0x1600, 0x55550108),               # the mapping names a missing object
    (0x1600, 0x70000308),               # ... a missing subindex
    (0x1600, 0x20070020),               # ... an object that cannot be mapped
    (0x1600, 0x60000110),               # ... an input (TxPDO) object in an RxPDO
])
def test_sm_bits_none_for_an_invalid_assignment(slave, assign, mapping):
    if mapping is not None:
        slave.download(0x1600, 0, b"\x00")
        slave.download(0x1600, 1, u32(mapping))
        slave.download(0x1600, 0, b"\x01")
    slave.download(0x1C12, 0, b"\x00")
    slave.download(0x1C12, 1, struct.pack("<H", assign))
    slave.download(0x1C12, 0, b"\x01")
    assert slave.od.sm_bits(2) is None
    assert slave.od.rx_entries(2) == []


# -- mailbox-level behaviour ------------------------------------------------------------------

def test_repeated_counter_is_dropped(slave):
    request = mbx.encode_upload_request(0x1018, 1, 5)
    assert len(slave.raw(request)) == 1
    assert slave.raw(request) == []
    assert len(slave.raw(mbx.encode_upload_request(0x1018, 1, 6))) == 1
    # Counter 0 means "not used" (IgH): never a repeat.
    for _ in range(2):
        assert len(slave.raw(mbx.encode_upload_request(0x1018, 1, 0))) == 1


def test_server_counter_runs_1_to_7(slave):
    counters = [slave.raw(mbx.encode_upload_request(0x1018, 1, slave.counter()))[0][0].counter
                for _ in range(9)]
    assert counters == [1, 2, 3, 4, 5, 6, 7, 1, 2]


def mbx_error(slave: Slave, raw: bytes) -> int:
    replies = slave.server.handle(raw, PREOP)
    assert len(replies) == 1 and len(replies[0]) == slave.sm1
    header, content = decode(replies[0])
    assert header.type == MbxType.ERROR and isinstance(content, MailboxError)
    return content.detail


def test_mailbox_error_replies(slave):
    foe = mbx.encode_mailbox(MbxType.FOE, b"\x01\x00" + bytes(8), 1)
    assert mbx_error(slave, pad_to(foe, 128)) == MbxErrorDetail.UNSUPPORTED_PROTOCOL
    assert mbx_error(slave, b"\x0a\x00\x00") == MbxErrorDetail.SIZE_TOO_SHORT
    zero = bytes.fromhex("000000000023") + bytes(122)
    assert mbx_error(slave, zero) == MbxErrorDetail.INVALID_HEADER
    too_long = struct.pack("<HHBB", 123, 0, 0, 0x33) + bytes(122)     # > SM0 - 6
    assert mbx_error(slave, too_long) == MbxErrorDetail.INVALID_HEADER
    short_sdo = struct.pack("<HHBB", 6, 0, 0, 0x43) + bytes.fromhex("0020 40 0010 00"
                                                                    .replace(" ", ""))
    assert mbx_error(slave, pad_to(short_sdo, 128)) == MbxErrorDetail.SIZE_TOO_SHORT
    rxpdo = mbx.encode_mailbox(MbxType.COE, struct.pack("<H", 5 << 12) + bytes(8), 5)
    assert mbx_error(slave, pad_to(rxpdo, 128)) == MbxErrorDetail.SERVICE_NOT_SUPPORTED
    channel = mbx.encode_mailbox(MbxType.COE, bytes(10), 6, channel=1)
    assert mbx_error(slave, pad_to(channel, 128)) == MbxErrorDetail.INVALID_CHANNEL


def test_sdo_information_is_answered_when_the_device_has_it(slave):
    # The device says CoE@SdoInfo: an OD-list request (opcode 1, list type 1 = all objects)
    # gets the list (opcode 2), in index order; an unknown opcode (9) an information error.
    # (A device without SdoInfo: tests/test_od.py.)
    request = mbx.encode_mailbox(MbxType.COE, struct.pack("<HBBHH", 8 << 12, 1, 0, 0, 1), 1)
    (header, info), = slave.raw(request)
    assert isinstance(info, SdoInfo) and info.opcode == 2 and not info.incomplete
    list_type, indices = mbx.decode_od_list(info.body)
    assert list_type == 1 and indices == sorted(indices) and {0x1000, 0x1018} <= set(indices)
    request = mbx.encode_mailbox(MbxType.COE, struct.pack("<HBBHH", 8 << 12, 9, 0, 0, 1), 2)
    (header, info), = slave.raw(request)
    assert isinstance(info, SdoInfo) and info.opcode == 7 and info.abort_code == 0x06010000


# -- the client on its own -------------------------------------------------------------------

def test_client_requests_are_padded_and_numbered():
    counter = MailboxCounter(6)
    txn = SdoDownload(0x1C12, 0, b"\x01", mbx_out_size=128, counter=counter)
    request = txn.first_request()
    assert len(request) == 128
    assert request[:16] == bytes.fromhex("0a000000007300202f121c0001000000")
    assert SdoUpload(0x1000, 0, counter=counter).first_request()[5] == 0x13    # 7 -> 1


def test_client_collects_emergencies_while_waiting():
    txn = SdoUpload(0x1018, 1, counter=MailboxCounter())
    txn.first_request()
    assert txn.on_response(mbx.encode_emergency(0x8130, 0x11, b"\x01", 1)) is None
    assert not txn.done
    assert txn.on_response(mbx.encode_upload_expedited(0x1018, 1, u32(2), 2)) is None
    assert txn.done and txn.result == u32(2)
    assert [e.error_code for e in txn.emergencies] == [0x8130]


def test_client_raises_the_abort_with_its_name():
    txn = SdoDownload(0x6060, 0, b"\x08", counter=MailboxCounter())
    txn.first_request()
    with pytest.raises(SdoAbort, match=r"0x06090030 \(value range of parameter exceeded"):
        txn.on_response(mbx.encode_abort(0x6060, 0, 0x06090030, 1))
    assert txn.done


@pytest.mark.parametrize("reply", [
    mbx.encode_upload_expedited(0x1018, 2, u32(1), 1),            # another subindex
    mbx.encode_download_response(0x1018, 1, 1),                   # a download's answer
    mbx.encode_mailbox(MbxType.EOE, bytes(10), 1),                # another protocol
    b"\x01\x02",                                                  # no header at all
])
def test_client_refuses_nonsense(reply):
    txn = SdoUpload(0x1018, 1, counter=MailboxCounter())
    txn.first_request()
    with pytest.raises(MailboxProtocolError) as err:
        txn.on_response(reply)
    assert err.value.abort_code == 0x05040001
    abort = decode(txn.abort_request(err.value.abort_code))[1]
    assert abort == Abort(0x1018, 1, 0x05040001)


def test_client_reports_a_mailbox_error_reply():
    txn = SdoUpload(0x1018, 1, counter=MailboxCounter())
    txn.first_request()
    with pytest.raises(MailboxProtocolError, match="unsupported protocol") as err:
        txn.on_response(mbx.encode_mailbox_error(2, 1))
    assert err.value.detail == 2


def test_client_checks_the_upload_toggle():
    txn = SdoUpload(0x2000, 0, counter=MailboxCounter())
    txn.first_request()
    nxt = txn.on_response(mbx.encode_upload_normal(0x2000, 0, 150, b"a" * 112, 1))
    assert decode(nxt)[1] == mbx.UploadSegmentRequest(False)
    with pytest.raises(MailboxProtocolError, match="toggle") as err:
        txn.on_response(mbx.encode_upload_segment(b"b" * 38, True, True, 2))
    assert err.value.abort_code == 0x05030000


def test_client_expedited_only_without_complete_access():
    counter = MailboxCounter()
    assert SdoDownload(0x1C12, 0, b"\x00\x00", True, 128, counter).first_request()[8] == 0x31
    assert SdoDownload(0x1C12, 0, b"\x00\x00", False, 128, counter).first_request()[8] == 0x2B
    assert SdoDownload(0x2000, 0, b"12345", False, 128, counter).first_request()[8] == 0x21


# -- real devices from the corpus ------------------------------------------------------------

def corpus_device(corpus: Path, relative: str, selector: str | None = None):
    lib = Library([corpus / "esi" / relative], cache=False)
    return lib.device(selector) if selector else lib.device(lib.entries[0])


def default_bits(device, sm: int) -> int:
    return sum(p.bit_length for p in device.pdos if p.sm == sm and not p.virtual)


def test_elmo_gold_drive(corpus):
    dev = corpus_device(corpus, "drives/Elmo_ECAT_00010420_V11.xml", "0x9a:0x30924:0x10420")
    od = ObjectDictionary.from_device(dev)
    assert od.sm_bits(2) == default_bits(dev, 2) == 80
    assert od.sm_bits(3) == default_bits(dev, 3)
    s = Slave(od, 0x8C, 0x8C)
    assert [s.upload(0x1018, i) for i in range(1, 5)] == [u32(0x9A), u32(0x30924),
                                                          u32(0x10420), u32(0)]
    assert s.upload(0x1018, 0, ca=True) == bytes.fromhex("0400") + u32(0x9A) \
        + u32(0x30924) + u32(0x10420) + u32(0)
    # The ESI types 0x1C00's entries UINT; a slave answers UNSIGNED8 (ETG.1000.6), which is
    # what SOEM reads them into.
    assert [s.upload(0x1C00, i) for i in range(5)] == [b"\x04", b"\x01", b"\x02", b"\x03",
                                                       b"\x04"]
    # The assignment a TwinCAT ENI downloads for this drive (docs/eni-exports.md §5).
    s.download(0x1C12, 0, b"\x00")
    s.download(0x1C12, 1, struct.pack("<H", 0x160A))
    s.download(0x1C12, 0, b"\x01")
    assert od.sm_bits(2) == sum(p.bit_length for p in dev.rx_pdos if p.index == 0x160A)
    with pytest.raises(SdoAbort) as err:
        s.download(0x1C12, 0, b"\x00", state=SAFEOP)
    assert err.value.code == 0x08000022


def test_soes_lan9252_demo(corpus):
    dev = corpus_device(corpus, "open-stacks/soes-linux_lan9252demo/slave.xml")
    od = ObjectDictionary.from_device(dev)
    assert od.sm_bits(2) == default_bits(dev, 2) == 16
    assert od.sm_bits(3) == default_bits(dev, 3) == 8
    s = Slave(od)
    assert s.upload(0x1018, 1) == u32(0x1337) and s.upload(0x1018, 2) == u32(1234)
    assert s.upload(0x1000, 0) == u32(0x01901389)
    assert s.upload(0x1008, 0) == b"evb9252_dig"
    assert s.upload(0x1009, 0) == b"1.0"                      # STRING(0): as long as given
    assert s.upload(0x1C12, 0, ca=True) == bytes.fromhex("01000016")
    with pytest.raises(SdoAbort) as err:                      # no PdoAssign in the ESI
        s.download(0x1C12, 0, b"\x00")
    assert err.value.code == 0x06010002


def test_every_coe_device_of_the_corpus_builds_a_dictionary(corpus):
    lib = Library([corpus / "esi"], cache=False)
    count = 0
    for e in lib.entries:
        dev = lib.device(e)
        if not has_coe(dev):
            continue
        count += 1
        od = ObjectDictionary.from_device(dev)
        where = f"{e.file}:{e.line}"
        assert [od.int_value(0x1018, i) for i in (1, 2, 3)] == \
            [dev.vendor.id, dev.product_code, dev.revision], where
        assert od.int_value(0x1C00, 0) == len(dev.sms), where
        for sm in dev.sms:
            if sm.type in ("Outputs", "Inputs"):
                assert od.sm_bits(sm.number) == default_bits(dev, sm.number), where
        # Sizes as SOEM's config_map reads them (1-byte counts and SM types, 2-byte PDO
        # indices, 4-byte mapping entries).
        s = Slave(od)
        assert len(s.upload(0x1000, 0)) == 4, where
        assert [len(s.upload(0x1C00, i)) for i in range(len(dev.sms) + 1)] == \
            [1] * (len(dev.sms) + 1), where
        for sm in dev.sms:
            if sm.type in ("Outputs", "Inputs"):
                assign = 0x1C10 + sm.number
                assert len(s.upload(assign, 0)) == 1, where
                for k in range(1, od.int_value(assign, 0) + 1):
                    pdo = s.upload(assign, k)
                    assert len(pdo) == 2, where
                    mapping = int.from_bytes(pdo, "little")
                    assert len(s.upload(mapping, 0)) == 1, where
                    for j in range(1, od.int_value(mapping, 0) + 1):
                        assert len(s.upload(mapping, j)) == 4, where
    assert count == 90
