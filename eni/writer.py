"""Write a :class:`NetworkPlan` as an ENI file (ETG.2100 ``EtherCATConfig``, version 1.3).

Element order follows the 2011 schema (``schemas/eni-1.3/EtherCATConfig.xsd``); the spelling
follows what TwinCAT and EC-Engineer write (``docs/eni-exports.md`` §1): integers in decimal
(uint32 values from 2^31 up in their signed spelling, see :func:`_uint32`), ``Data`` as
lowercase hex bytes in wire order, PDO and entry indices ESI style (``#x1a00``), booleans
``1``/``0`` (EC-Engineer's spelling, and the only one ``PreviousPort/@Selected``, an xs:int,
accepts).  The output is deterministic: the same plan gives the same bytes.

The slave/master InitCmd ``timeout`` is not written: the 2011 schema's ``ECatCmdType`` has no
``Timeout`` (eni-exports §3), so the compiler carries poll timeouts in ``Validate``.
"""

from __future__ import annotations

import re
from pathlib import Path

from ecatcfg.eni.plan import (
    BitRange,
    CoeInitCmd,
    Cyclic,
    CyclicCmd,
    DcPlan,
    EoeInitCmd,
    FoeInitCmd,
    HotConnectPlan,
    InitCmd,
    MailboxArea,
    MailboxPlan,
    MasterPlan,
    NetworkPlan,
    PassiveSlave,
    PdoDesc,
    PdoEntryDesc,
    PreviousPort,
    ProcessData,
    ProcessImage,
    SlavePlan,
    SmSettings,
    SoeInitCmd,
    Variable,
)
from ecatcfg.fileio import write_atomic

_XSI = "http://www.w3.org/2001/XMLSchema-instance"
_DECLARATION = b'<?xml version="1.0" encoding="UTF-8"?>\n'


def to_bytes(plan: NetworkPlan, generator: str | None = None) -> bytes:
    """The ENI document for ``plan``; ``generator`` goes into a leading
    ``<!-- Created with ... -->`` comment (as EC-Engineer writes one)."""
    doc = _Document()
    if generator is not None:
        # "--" may not occur inside an XML comment.
        text = _checked(f" Created with {re.sub('-(?=-)', '- ', generator)} ")
        doc.parts.append(f"<!--{text}-->\n")
    root = doc.root("EtherCATConfig")
    root.set("xmlns:xsi", _XSI)
    if plan.version is not None:
        root.set("Version", plan.version)
    root.set("xsi:noNamespaceSchemaLocation", "EtherCATConfig.xsd")
    config = _sub(root, "Config")
    _master(config, plan.master)
    for slave in plan.in_file_order():
        if isinstance(slave, PassiveSlave):
            _passive(config, slave)
        else:
            _slave(config, slave)
    for cyclic in plan.cyclic:
        _cyclic(config, cyclic)
    _process_image(config, plan.process_image)
    return _DECLARATION + doc.finish().encode("utf-8")


def write(plan: NetworkPlan, path: str | Path, generator: str | None = None) -> None:
    """Write ``plan`` to ``path`` atomically."""
    write_atomic(path, to_bytes(plan, generator))


# --- the document ---------------------------------------------------------------------------
#
# The ENI is written as text in document order, as lxml's ``tostring(pretty_print=True)``
# spells a tree (two spaces per level, ``<Tag/>`` for an element with neither text nor
# children, ``<Tag></Tag>`` for an empty text, libxml2's escapes): building the tree of a
# 512-slave line (330 000 elements: 16 000 InitCmds, 36 000 PDO entries) and serialising it
# took longer than compiling the line.  ``tests/test_eni_writer.py`` holds the spelling to
# lxml's for every character and every shape the writer makes.

# Characters XML 1.0 does not allow (§2.2), refused as lxml refuses them when a text is set.
_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff\ud800-\udfff]")
_TEXT_SPECIAL = re.compile("[&<>\r]")
_ATTR_SPECIAL = re.compile('[&<>"\n\r\t]')
_ESCAPES = {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "\n": "&#10;",
            "\r": "&#13;", "\t": "&#9;"}


def _escape_match(m: re.Match[str]) -> str:
    return _ESCAPES[m.group()]


def _checked(value: str) -> str:
    if _NOT_XML.search(value):
        raise ValueError("All strings must be XML compatible: Unicode or ASCII, no NULL bytes "
                         f"or control characters ({value!r})")
    return value


def _text_escaped(value: str) -> str:
    """Element text as libxml2 writes it: ``&``, ``<``, ``>`` and carriage return escaped."""
    return _TEXT_SPECIAL.sub(_escape_match, _checked(value))


def _attr_escaped(value: str) -> str:
    """An attribute value in double quotes: also ``"``, newline and tab escaped."""
    return _ATTR_SPECIAL.sub(_escape_match, _checked(value))


class _Document:
    """The text of the document being written, and its elements still open."""

    __slots__ = ("parts", "open", "escaped")

    def __init__(self) -> None:
        self.parts: list[str] = []
        self.open: list[Element] = []
        self.escaped: dict[str, str] = {}

    def root(self, tag: str) -> Element:
        el = Element(self, tag, "")
        self.open.append(el)
        return el

    def finish(self) -> str:
        while self.open:
            self.open.pop().close()
        return "".join(self.parts)


class Element:
    """An element being written.  Its attributes are set before its first child; its start
    tag is written with the first child (or as ``<Tag/>`` when it closes without one).  A
    child added to an element closes the element's open descendants."""

    __slots__ = ("doc", "tag", "indent", "attrs", "started")

    def __init__(self, doc: _Document, tag: str, indent: str) -> None:
        self.doc = doc
        self.tag = tag
        self.indent = indent
        self.attrs = ""
        self.started = False

    def set(self, name: str, value: str) -> None:
        if self.started:
            raise ValueError(f"<{self.tag}>: attribute {name} set after its first child")
        self.attrs += f' {name}="{_attr_escaped(value)}"'

    def enter(self) -> None:
        """Make this the innermost open element, its start tag written."""
        stack = self.doc.open
        while stack[-1] is not self:
            stack.pop().close()
        if not self.started:
            self.started = True
            self.doc.parts.append(f"{self.indent}<{self.tag}{self.attrs}>\n")

    def close(self) -> None:
        if self.started:
            self.doc.parts.append(f"{self.indent}</{self.tag}>\n")
        else:
            self.doc.parts.append(f"{self.indent}<{self.tag}{self.attrs}/>\n")


# --- value spelling -------------------------------------------------------------------------

def _sub(parent: Element, tag: str) -> Element:
    """A child element, to be given attributes and children."""
    if not parent.started or parent.doc.open[-1] is not parent:
        parent.enter()
    el = Element(parent.doc, tag, parent.indent + "  ")
    parent.doc.open.append(el)
    return el


def _leaf(parent: Element, tag: str, text: str) -> None:
    """A child element holding ``text`` (written now: it takes no attributes or children)."""
    # Texts repeat (InitCmd comments, entry names and types): each is checked once.
    escaped = parent.doc.escaped.get(text)
    if escaped is None:
        escaped = parent.doc.escaped[text] = _text_escaped(text)
    _safe_leaf(parent, tag, escaped)


def _safe_leaf(parent: Element, tag: str, text: str) -> None:
    """:func:`_leaf` for a text known to need no escape (digits, hex)."""
    if not parent.started or parent.doc.open[-1] is not parent:
        parent.enter()
    parent.doc.parts.append(f"{parent.indent}  <{tag}>{text}</{tag}>\n")


def _bool(value: bool) -> str:
    return "1" if value else "0"


def _int(parent: Element, tag: str, value: int) -> None:
    # _safe_leaf, inlined: a 512-slave line has 130 000 numbers.
    if not parent.started or parent.doc.open[-1] is not parent:
        parent.enter()
    parent.doc.parts.append(f"{parent.indent}  <{tag}>{value}</{tag}>\n")


def _uint32(parent: Element, tag: str, value: int) -> None:
    """A uint32 (identity, logical address) in a schema ``xs:int``: values from 2^31 up are
    written as their signed 32-bit twin (0xE0000ECA -> -536867126), which validates and
    which int32 parsers in masters read back to the same bits; the reader masks them."""
    if not 0 <= value <= 0xFFFFFFFF:
        raise ValueError(f"<{tag}> {value} is not a 32-bit unsigned value")
    _int(parent, tag, value - (1 << 32) if value & 0x80000000 else value)


def _opt_int(parent: Element, tag: str, value: int | None) -> None:
    if value is not None:
        _int(parent, tag, value)


def _hex(parent: Element, tag: str, value: bytes) -> None:
    _safe_leaf(parent, tag, value.hex())


def _text(parent: Element, tag: str, value: str) -> None:
    """A string field where "" means absent (the reader gives "" for a missing element)."""
    if value:
        _leaf(parent, tag, value)


def _opt_text(parent: Element, tag: str, value: str | None) -> None:
    """An optional string field: None is absent, "" an empty element."""
    if value is not None:
        _leaf(parent, tag, value)


def _index(value: int) -> str:
    """PDO and entry indices as ESI writes them (eni-exports §1)."""
    return f"#x{value:04x}"


def _set_flag(el: Element, name: str, value: bool) -> None:
    """An optional boolean attribute: written only when true (absent means false)."""
    if value:
        el.set(name, _bool(True))


# --- commands -------------------------------------------------------------------------------

def _address(el: Element, adp: int | None, ado: int | None, addr: int | None) -> None:
    """``(Adp?, Ado) | Addr``: physical or logical addressing, never both."""
    if addr is not None:
        if adp is not None or ado is not None:
            raise ValueError("a command has both a logical Addr and Adp/Ado")
        _uint32(el, "Addr", addr)
        return
    if ado is None:
        raise ValueError("a command needs Ado (physical) or Addr (logical)")
    _opt_int(el, "Adp", adp)
    _int(el, "Ado", ado)


def _payload(el: Element, data: bytes | None, length: int) -> None:
    """``Data | DataLength``: ``data is None`` means ``length`` zero bytes."""
    if data is None:
        _int(el, "DataLength", length)
        return
    if len(data) != length:
        raise ValueError(f"command length {length} differs from its {len(data)} data bytes")
    _hex(el, "Data", data)


def _init_cmd(parent: Element, cmd: InitCmd, tag: str = "InitCmd") -> None:
    """An ``ECatCmdType`` command: an ``InitCmd``, or a hot-connect ``IdentifyCmd``."""
    el = _sub(parent, tag)
    for transition in cmd.transitions:
        _leaf(el, "Transition", transition.value)
    if cmd.before_slave is not None:
        _safe_leaf(el, "BeforeSlave", _bool(cmd.before_slave))
    _text(el, "Comment", cmd.comment)
    _opt_text(el, "Requires", cmd.requires)
    _int(el, "Cmd", cmd.cmd)
    _address(el, cmd.adp, cmd.ado, cmd.addr)
    _payload(el, cmd.data, cmd.length)
    _opt_int(el, "Cnt", cmd.cnt)
    _opt_int(el, "Retries", cmd.retries)
    if cmd.validate is not None:
        validate = _sub(el, "Validate")
        if cmd.validate.compare is not None:
            # Beyond the 1.3 schema, as exporters write it (eni/compare.py): kept, not lost.
            validate.set("Type", cmd.validate.compare)
        _hex(validate, "Data", cmd.validate.data)
        if cmd.validate.mask is not None:
            _hex(validate, "DataMask", cmd.validate.mask)
        _int(validate, "Timeout", cmd.validate.timeout)
    # cmd.timeout: no place for it in the 2011 ECatCmdType (module docstring).


def _init_cmds(parent: Element, cmds: list[InitCmd]) -> None:
    el = _sub(parent, "InitCmds")
    for cmd in cmds:
        _init_cmd(el, cmd)


# --- master ---------------------------------------------------------------------------------

def _master(config: Element, master: MasterPlan) -> None:
    el = _sub(config, "Master")
    info = _sub(el, "Info")
    _leaf(info, "Name", master.name)
    _hex(info, "Destination", master.destination)
    _hex(info, "Source", master.source)
    _hex(info, "EtherType", master.ether_type)
    if master.mailbox_states is not None:
        states = _sub(el, "MailboxStates")
        _uint32(states, "StartAddr", master.mailbox_states[0])
        _int(states, "Count", master.mailbox_states[1])
    _init_cmds(el, master.init_cmds)


# --- slaves ---------------------------------------------------------------------------------

def _slave(config: Element, slave: SlavePlan) -> None:
    el = _sub(config, "Slave")
    info = _sub(el, "Info")
    _leaf(info, "Name", slave.name)
    _int(info, "PhysAddr", slave.phys_addr)
    _int(info, "AutoIncAddr", slave.auto_inc_addr)
    _leaf(info, "Physics", slave.physics)
    _identity(info, slave)
    if slave.process_data is not None:
        _process_data(el, slave.process_data)
    if slave.mailbox is not None:
        _mailbox(el, slave.mailbox)
    _init_cmds(el, slave.init_cmds)
    for port in slave.previous_ports:
        _previous_port(el, port)
    if slave.hot_connect is not None:
        _hot_connect(el, slave.hot_connect)
    if slave.dc is not None:
        _dc(el, slave.dc)


def _identity(info: Element, slave: SlavePlan | PassiveSlave) -> None:
    _uint32(info, "VendorId", slave.vendor_id)
    _uint32(info, "ProductCode", slave.product_code)
    _uint32(info, "RevisionNo", slave.revision)
    _uint32(info, "SerialNo", slave.serial_no)


def _passive(config: Element, slave: PassiveSlave) -> None:
    """A slave without an ESC as TwinCAT writes one: ``Info`` without the ESC group
    (``PhysAddr``, ``AutoIncAddr``, ``Physics``; ETG.2100), an empty ``ProcessData``,
    ``PreviousPort``."""
    el = _sub(config, "Slave")
    info = _sub(el, "Info")
    _leaf(info, "Name", slave.name)
    _identity(info, slave)
    if slave.process_data:
        _sub(el, "ProcessData")
    for port in slave.previous_ports:
        _previous_port(el, port)


def _bit_range(parent: Element, tag: str, bits: BitRange) -> None:
    el = _sub(parent, tag)
    _int(el, "BitStart", bits.bit_start)
    _int(el, "BitLength", bits.bit_length)


def _process_data(parent: Element, pd: ProcessData) -> None:
    el = _sub(parent, "ProcessData")
    for bits in pd.send:
        _bit_range(el, "Send", bits)
    for bits in pd.recv:
        _bit_range(el, "Recv", bits)
    numbers = [sm.number for sm in pd.sms]
    if len(set(numbers)) != len(numbers) or not set(numbers) <= {0, 1, 2, 3}:
        raise ValueError(f"ProcessData SyncManagers must be distinct Sm0..Sm3, got {numbers}")
    for sm in sorted(pd.sms, key=lambda s: s.number):      # the schema orders Sm0..Sm3
        _sm(el, sm)
    for pdo in pd.pdos:
        _pdo(el, pdo)


def _sm(parent: Element, sm: SmSettings) -> None:
    el = _sub(parent, f"Sm{sm.number}")
    _leaf(el, "Type", sm.type)
    _opt_int(el, "MinSize", sm.min_size)
    _opt_int(el, "MaxSize", sm.max_size)
    _opt_int(el, "DefaultSize", sm.default_size)
    _int(el, "StartAddress", sm.start_address)
    _int(el, "ControlByte", sm.control_byte)
    _safe_leaf(el, "Enable", _bool(sm.enable))
    if sm.virtual is not None:
        _safe_leaf(el, "Virtual", _bool(sm.virtual))
    _opt_int(el, "Watchdog", sm.watchdog)
    for index in sm.pdos:
        _int(el, "Pdo", index)              # xs:int: decimal, as the real files write it


def _pdo(parent: Element, pdo: PdoDesc) -> None:
    if pdo.direction not in ("rx", "tx"):
        raise ValueError(f"PDO direction must be 'rx' or 'tx', got {pdo.direction!r}")
    el = _sub(parent, "RxPdo" if pdo.direction == "rx" else "TxPdo")
    _set_flag(el, "Fixed", pdo.fixed)
    _set_flag(el, "Mandatory", pdo.mandatory)
    _set_flag(el, "Virtual", pdo.virtual)
    if pdo.sm is not None:
        el.set("Sm", str(pdo.sm))
    _safe_leaf(el, "Index", _index(pdo.index))
    _leaf(el, "Name", pdo.name)
    for index in pdo.excludes:
        _safe_leaf(el, "Exclude", _index(index))
    for entry in pdo.entries:
        _entry(el, entry)


def _entry(parent: Element, entry: PdoEntryDesc) -> None:
    el = _sub(parent, "Entry")
    _safe_leaf(el, "Index", _index(entry.index))
    _int(el, "SubIndex", entry.subindex)
    _int(el, "BitLen", entry.bit_len)
    _text(el, "Name", entry.name)           # padding entries (index 0) have none
    _opt_text(el, "DataType", entry.data_type)


def _mailbox_area(parent: Element, tag: str, area: MailboxArea) -> Element:
    el = _sub(parent, tag)
    _int(el, "Start", area.start)
    _int(el, "Length", area.length)
    return el


def _mailbox(parent: Element, mb: MailboxPlan) -> None:
    el = _sub(parent, "Mailbox")
    if mb.data_link_layer is not None:
        el.set("DataLinkLayer", _bool(mb.data_link_layer))
    _mailbox_area(el, "Send", mb.send)
    recv = _mailbox_area(el, "Recv", mb.recv)
    _opt_int(recv, "PollTime", mb.poll_time)
    _opt_int(recv, "StatusBitAddr", mb.status_bit_addr)
    if (mb.bootstrap_send is None) != (mb.bootstrap_recv is None):
        raise ValueError("BootStrap needs both a send and a receive mailbox")
    if mb.bootstrap_send is not None and mb.bootstrap_recv is not None:
        boot = _sub(el, "BootStrap")
        _mailbox_area(boot, "Send", mb.bootstrap_send)
        _mailbox_area(boot, "Recv", mb.bootstrap_recv)
    for protocol in mb.protocols:
        _leaf(el, "Protocol", protocol)
    if mb.coe_init_cmds or mb.coe_profiles:
        _coe(el, mb)
    # ETG.2100 order: CoE, SoE, AoE, EoE, FoE, VoE.
    if mb.soe_init_cmds:
        cmds = _sub(_sub(el, "SoE"), "InitCmds")
        for soe_cmd in mb.soe_init_cmds:
            _soe_init_cmd(cmds, soe_cmd)
    if mb.aoe_net_id is not None:
        _leaf(_sub(el, "AoE"), "NetId", mb.aoe_net_id)
    if mb.eoe_init_cmds:
        cmds = _sub(_sub(el, "EoE"), "InitCmds")
        for eoe_cmd in mb.eoe_init_cmds:
            _eoe_init_cmd(cmds, eoe_cmd)
    if mb.foe_init_cmds:
        cmds = _sub(_sub(el, "FoE"), "InitCmds")
        for foe_cmd in mb.foe_init_cmds:
            _mailbox_cmd(cmds, foe_cmd)


def _coe(parent: Element, mb: MailboxPlan) -> None:
    el = _sub(parent, "CoE")
    if mb.coe_init_cmds:
        cmds = _sub(el, "InitCmds")
        for cmd in mb.coe_init_cmds:
            _coe_init_cmd(cmds, cmd)
    if mb.coe_profiles:
        profile = _sub(el, "Profile")
        for number, add_info in mb.coe_profiles:
            channel = _sub(profile, "ChannelInfo")
            _int(channel, "ProfileNo", number)
            _opt_text(channel, "AddInfo", add_info)


MailboxInitCmd = CoeInitCmd | EoeInitCmd | SoeInitCmd | FoeInitCmd


def _mailbox_cmd_head(parent: Element, cmd: MailboxInitCmd) -> Element:
    """What every mailbox InitCmd of ETG.2100 starts with: @Fixed, Transition+, Comment?,
    Timeout (required here, unlike in ECatCmdType)."""
    el = _sub(parent, "InitCmd")
    _set_flag(el, "Fixed", cmd.fixed)
    if isinstance(cmd, CoeInitCmd):
        _set_flag(el, "CompleteAccess", cmd.complete_access)
    for transition in cmd.transitions:
        _leaf(el, "Transition", transition.value)
    _text(el, "Comment", cmd.comment)
    _int(el, "Timeout", cmd.timeout)
    return el


def _mailbox_cmd_tail(el: Element, cmd: MailboxInitCmd) -> None:
    if cmd.disabled:
        _safe_leaf(el, "Disabled", _bool(True))


def _coe_init_cmd(parent: Element, cmd: CoeInitCmd) -> None:
    el = _mailbox_cmd_head(parent, cmd)
    _int(el, "Ccs", cmd.ccs)
    _int(el, "Index", cmd.index)
    _int(el, "SubIndex", cmd.subindex)
    _hex(el, "Data", cmd.data)
    _mailbox_cmd_tail(el, cmd)


def _eoe_init_cmd(parent: Element, cmd: EoeInitCmd) -> None:
    _mailbox_cmd(parent, cmd)


def _mailbox_cmd(parent: Element, cmd: EoeInitCmd | FoeInitCmd) -> None:
    """ETG.2100 ``MailboxCmdType``: Transition+, Comment?, Timeout, Data, Disabled?."""
    el = _mailbox_cmd_head(parent, cmd)
    _hex(el, "Data", cmd.data)
    _mailbox_cmd_tail(el, cmd)


def _soe_init_cmd(parent: Element, cmd: SoeInitCmd) -> None:
    """ETG.2100 ``Mailbox/SoE/InitCmds/InitCmd``: Transition+, Comment?, Timeout, OpCode,
    DriveNo, IDN, Elements, Attribute, Data?, Disabled?, @Fixed."""
    el = _mailbox_cmd_head(parent, cmd)
    _int(el, "OpCode", cmd.op_code)
    _int(el, "DriveNo", cmd.drive_no)
    _int(el, "IDN", cmd.idn)
    _int(el, "Elements", cmd.elements)
    _uint32(el, "Attribute", cmd.attribute)     # the IDN's 32-bit attribute, in an xs:int
    if cmd.data:
        _hex(el, "Data", cmd.data)
    _mailbox_cmd_tail(el, cmd)


def _previous_port(parent: Element, port: PreviousPort) -> None:
    el = _sub(parent, "PreviousPort")
    if port.selected is not None:
        el.set("Selected", _bool(port.selected))     # xs:int in the 2011 schema
    _leaf(el, "Port", port.port)
    _opt_int(el, "PhysAddr", port.phys_addr)


def _hot_connect(parent: Element, group: HotConnectPlan) -> None:
    """ETG.2100 ``HotConnect``: GroupMemberCnt, then one or more IdentifyCmd."""
    if not group.identify_cmds:
        raise ValueError("a HotConnect group needs at least one IdentifyCmd (ETG.2100)")
    el = _sub(parent, "HotConnect")
    _int(el, "GroupMemberCnt", group.member_count)
    for cmd in group.identify_cmds:
        _init_cmd(el, cmd, "IdentifyCmd")


def _dc(parent: Element, dc: DcPlan) -> None:
    el = _sub(parent, "DC")
    _safe_leaf(el, "ReferenceClock", _bool(dc.reference_clock))
    _int(el, "CycleTime0", dc.cycle_time0)
    _int(el, "CycleTime1", dc.cycle_time1)
    _int(el, "ShiftTime", dc.shift_time)


# --- cyclic frames and process image --------------------------------------------------------

def _cyclic(config: Element, cyclic: Cyclic) -> None:
    if not cyclic.frames or not all(frame.cmds for frame in cyclic.frames):
        raise ValueError("a Cyclic needs at least one Frame, and each Frame a Cmd")
    el = _sub(config, "Cyclic")
    _opt_text(el, "Comment", cyclic.comment)
    _opt_int(el, "CycleTime", cyclic.cycle_time)
    for frame in cyclic.frames:
        frame_el = _sub(el, "Frame")
        _opt_text(frame_el, "Comment", frame.comment)
        for cmd in frame.cmds:
            _cyclic_cmd(frame_el, cmd)


def _cyclic_cmd(parent: Element, cmd: CyclicCmd) -> None:
    el = _sub(parent, "Cmd")
    for state in cmd.states:
        _leaf(el, "State", state)
    _text(el, "Comment", cmd.comment)
    _int(el, "Cmd", cmd.cmd)
    _address(el, cmd.adp, cmd.ado, cmd.addr)
    _payload(el, cmd.data, cmd.length)
    _opt_int(el, "Cnt", cmd.cnt)
    _int(el, "InputOffs", cmd.input_offs)
    _int(el, "OutputOffs", cmd.output_offs)
    if cmd.copy_infos:           # last in the Cmd's sequence (ETG.2100 CopyInfosType)
        copies = _sub(el, "CopyInfos")
        for copy in cmd.copy_infos:
            info = _sub(copies, "CopyInfo")
            _int(info, "SrcBitOffs", copy.src_bit_offs)
            _int(info, "DstBitOffs", copy.dst_bit_offs)
            _int(info, "BitSize", copy.bit_size)


def _process_image(config: Element, image: ProcessImage) -> None:
    el = _sub(config, "ProcessImage")
    for tag, size, variables in (("Inputs", image.inputs_size, image.inputs),
                                 ("Outputs", image.outputs_size, image.outputs)):
        part = _sub(el, tag)
        _int(part, "ByteSize", size)
        for variable in variables:
            _variable(part, variable)


def _variable(parent: Element, var: Variable) -> None:
    el = _sub(parent, "Variable")
    _leaf(el, "Name", var.name)
    _opt_text(el, "Comment", var.comment)
    _opt_text(el, "DataType", var.data_type)
    _int(el, "BitSize", var.bit_size)
    _int(el, "BitOffs", var.bit_offs)
