"""Read an ENI file (ETG.2100 ``EtherCATConfig``) into a :class:`NetworkPlan`.

Tolerant of what real exporters write (``docs/eni-exports.md`` §1, §8): booleans ``1``/``0`` or
``true``/``false``, numbers decimal or ``#x``/``0x`` hex, ``InitCmd/Timeout`` (newer than the
2011 schema), an ``EncryptedEtherCATConfig`` root with a clear-text body.  What the plan needs
and the file lacks or misspells is an :class:`EniReadError` naming the file and the element's
line.

Nothing is dropped silently: which elements the reader takes, which it accepts without
using them (and why), and which ask for what ``apply`` does not do is one explicit list,
:mod:`ecatcfg.eni.contents`.  The refused and the unknown ones are recorded in
``NetworkPlan.unsupported`` with their line, slave and command count; refusing or skipping
them is the runtime's call (``apply --skip-unsupported``), not the reader's.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

from lxml import etree

from ecatcfg.eni.plan import (
    COPY_ELEMENT,
    FIRST_STATION_ADDRESS,
    BitRange,
    CoeInitCmd,
    CopyInfo,
    Cyclic,
    CyclicCmd,
    DcPlan,
    EoeInitCmd,
    FoeInitCmd,
    Frame,
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
    Unsupported,
    Validate,
    Variable,
)
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import FRAME_PAYLOAD, MAX_DATAGRAM_DATA, Transition, frame_bytes
from ecatcfg.esi import xmlsafe
from ecatcfg.esi.idn import MAX_DRIVE
from ecatcfg.esi.values import SPELLABLE, parse_bool, parse_hex_bytes, parse_int
from ecatcfg.fileio import read_input

Element = etree._Element


class _Node(Protocol):
    """What the lookups below use: an element, or its :class:`_Children` view."""

    @property
    def tag(self) -> object: ...
    @property
    def sourceline(self) -> int | None: ...
    def find(self, tag: str, /) -> Element | None: ...
    def iterchildren(self, tag: str, /) -> Iterator[Element]: ...
    def get(self, name: str, /) -> str | None: ...

_ROOTS = ("EtherCATConfig", "EncryptedEtherCATConfig")
_DC_VALUES = ("ReferenceClock", "CycleTime0", "CycleTime1", "ShiftTime")

# What the plan can put on the wire (ETG.1000.4 datagram fields) or keep in memory; a value
# outside is an error at its line, never a wrapped number or a crash of the master.
# (lo, hi, what the field is)
Bounds = tuple[int, int, str]
U8: Bounds = (0, 0xFF, "one byte")
U16: Bounds = (0, 0xFFFF, "16 bits")
# xs:int fields that hold an unsigned value may spell it signed (TwinCAT: AutoIncAddr -1).
S16: Bounds = (-0x8000, 0xFFFF, "16 bits")
S32: Bounds = (-0x8000_0000, 0xFFFF_FFFF, "32 bits")
I32: Bounds = (-0x8000_0000, 0x7FFF_FFFF, "a signed 32-bit number")
COUNT: Bounds = (0, 0x7FFF_FFFF, "0 or more")
# One datagram carries at most 1486 data bytes (a frame's 1500 minus the EtherCAT and the
# datagram headers; SOEM's EC_MAXMBX): a command's data, and a mailbox, which is read and
# written whole, in one datagram.
DATAGRAM: Bounds = (0, MAX_DATAGRAM_DATA, "what one datagram carries")
# The process image is kept in memory: sizes and offsets stay below 1 MiB (ETG.2100 sets no
# limit; real images are a few KiB).
IMAGE_BYTES = 1 << 20
IMAGE: Bounds = (0, IMAGE_BYTES, "the process image this master keeps (1 MiB)")
IMAGE_BITS: Bounds = (0, 8 * IMAGE_BYTES, "the process image this master keeps (1 MiB)")
VARIABLE_BITS: Bounds = (1, 8 * IMAGE_BYTES, "1 bit or more, within the process image (1 MiB)")
SM_NUMBER: Bounds = (0, 15, "an ESC has SyncManagers 0..15")
# The SoE mailbox header's OpCode and drive number are 3 bits each (ETG.1000.6 §5.8).
SOE_OPCODE: Bounds = (0, 7, "an SoE OpCode (3 bits)")
SOE_DRIVE: Bounds = (0, MAX_DRIVE, "an SoE drive number (3 bits)")


class EniReadError(EcatcfgError):
    """An ENI file this reader cannot turn into a plan."""


def _parse_int(text: str) -> int | None:
    """A number as ESI and ENI files write it (:func:`ecatcfg.esi.values.parse_int`: decimal,
    ``#x`` or ``0x`` hex); ``None`` if it is none of those."""
    try:
        # Every field's own bounds are checked by the reader (``_Reader.check``), which names
        # the field's range; the syntax allows at most 4,000 hex digits (16,000 bits).
        return parse_int(text, -SPELLABLE, SPELLABLE)
    except ValueError:
        return None



def _shown(value: int) -> str:
    """``value`` for a message.  A number the file spells in thousands of hex digits
    (``esi.values.parse_int`` takes up to 4,000) is past Python's 4,300-digit limit for
    ``str()`` (a ``ValueError`` inside the error itself): shown by its size instead."""
    if abs(value) < 1 << 64:
        return str(value)
    return f"{'-' if value < 0 else ''}(a number of {value.bit_length()} bits)"


def _parse_bool(text: str) -> bool | None:
    try:
        return parse_bool(text)
    except ValueError:
        return None


def read_file(path: str | Path, shown_as: str | None = None) -> NetworkPlan:
    """Read the ENI at ``path``; errors name ``shown_as`` (the path as the user gave it)."""
    name = shown_as or str(path)
    try:
        data = read_input(path, name)
    except OSError as exc:
        raise EniReadError(f"cannot read: {exc.strerror}", name) from None
    return read_bytes(data, name)


def read_bytes(data: bytes, shown_as: str) -> NetworkPlan:
    """Read an ENI held in memory; ``shown_as`` names it in messages."""
    tree = xmlsafe.parse_bytes(data, shown_as, strip=True)   # refuses entities and DTDs
    return _Reader(shown_as).network(tree.getroot())


class _Children:
    """An element whose children are looked up by tag many times (an InitCmd: a dozen).

    ``find``, ``iterchildren``, ``get``, ``tag`` and ``sourceline`` answer as the element's
    own would (``find`` for a plain tag: the first such child), but ``find`` is a dict
    lookup built in one pass over the children, not a search per call.
    """

    __slots__ = ("el", "tag", "sourceline", "_first")

    def __init__(self, el: Element) -> None:
        self.el, self.tag, self.sourceline = el, el.tag, el.sourceline
        first: dict[object, Element] = {}
        for child in el:
            first.setdefault(child.tag, child)
        self._first = first

    def find(self, tag: str) -> Element | None:
        return self._first.get(tag)

    def iterchildren(self, tag: str) -> Iterator[Element]:
        return self.el.iterchildren(tag)

    def get(self, name: str) -> str | None:
        return self.el.get(name)


class _Reader:
    """Element-to-plan conversion; every error carries the file and the element's line."""

    def __init__(self, file: str) -> None:
        self.file = file
        # InitCmds the reader leaves out: refused parts (eni/contents.py dropped_init_cmds).
        self._dropped: set[Element] = set()
        self._copy_lines: dict[int, int | None] = {}

    def error(self, message: str, el: _Node) -> EniReadError:
        return EniReadError(message, self.file, el.sourceline)

    # --- values ---------------------------------------------------------------------------

    @staticmethod
    def text(el: Element) -> str:
        """An element's text, CDATA included, comments left out."""
        if len(el) == 0:            # no child elements or comments: the text is all of it
            return el.text or ""
        return "".join(el.itertext())

    def child(self, parent: _Node, tag: str) -> Element:
        el = parent.find(tag)
        if el is None:
            raise self.error(f"<{parent.tag!s}> has no <{tag}>", parent)
        return el

    def number(self, el: Element, bounds: Bounds) -> int:
        text = self.text(el)
        value = _parse_int(text)
        if value is None:
            raise self.error(f"<{el.tag!s}> is not a number: {text.strip()!r}", el)
        self.check(value, bounds, f"<{el.tag!s}>", el)
        return value

    def check(self, value: int, bounds: Bounds, what: str, el: _Node) -> None:
        """``value`` of ``what`` (``<Cmd>``, ``attribute Sm of <Pdo>:``) within ``bounds``."""
        if not bounds[0] <= value <= bounds[1]:
            lo, hi, range_text = bounds
            raise self.error(f"{what} {_shown(value)} is out of range: {range_text} "
                             f"({lo}..{hi})", el)

    def req_int(self, parent: _Node, tag: str, bounds: Bounds) -> int:
        return self.number(self.child(parent, tag), bounds)

    def opt_int(self, parent: _Node, tag: str, bounds: Bounds) -> int | None:
        el = parent.find(tag)
        return None if el is None else self.number(el, bounds)

    def int_or(self, parent: _Node, tag: str, default: int, bounds: Bounds) -> int:
        value = self.opt_int(parent, tag, bounds)
        return default if value is None else value

    def uint32(self, parent: _Node, tag: str) -> int:
        """A uint32 the schema types xs:int: negative values are its signed spelling."""
        return self.req_int(parent, tag, S32) & 0xFFFFFFFF

    def attr_int(self, el: _Node, name: str, bounds: Bounds) -> int | None:
        text = el.get(name)
        if text is None:
            return None
        value = _parse_int(text)
        if value is None:
            raise self.error(f"attribute {name} of <{el.tag!s}> is not a number: {text!r}", el)
        self.check(value, bounds, f"attribute {name} of <{el.tag!s}>:", el)
        return value

    def boolean(self, el: Element) -> bool:
        value = _parse_bool(self.text(el))
        if value is None:
            raise self.error(f"<{el.tag!s}> is not a boolean: {self.text(el).strip()!r}", el)
        return value

    def opt_bool(self, parent: _Node, tag: str) -> bool | None:
        el = parent.find(tag)
        return None if el is None else self.boolean(el)

    def attr_bool(self, el: _Node, name: str) -> bool | None:
        text = el.get(name)
        if text is None:
            return None
        value = _parse_bool(text)
        if value is None:
            raise self.error(f"attribute {name} of <{el.tag!s}> is not a boolean: {text!r}", el)
        return value

    def hex_bytes(self, el: Element) -> bytes:
        try:
            return parse_hex_bytes(self.text(el))
        except ValueError as exc:
            raise self.error(f"<{el.tag!s}>: {exc}", el) from None

    def opt_hex(self, parent: _Node, tag: str) -> bytes | None:
        el = parent.find(tag)
        return None if el is None else self.hex_bytes(el)

    def hex_or(self, parent: _Node, tag: str, default: bytes) -> bytes:
        value = self.opt_hex(parent, tag)
        return default if value is None else value

    def opt_text(self, parent: _Node, tag: str) -> str | None:
        el = parent.find(tag)
        return None if el is None else self.text(el)

    def transitions(self, parent: _Node) -> list[Transition]:
        result = []
        for el in parent.iterchildren("Transition"):
            name = self.text(el).strip()
            try:
                result.append(Transition(name))
            except ValueError:
                raise self.error(f"unknown transition {name!r}", el) from None
        return result

    # --- document -------------------------------------------------------------------------

    def network(self, root: Element) -> NetworkPlan:
        if root.tag not in _ROOTS:
            raise self.error(f"not an ENI file: the root element is <{root.tag!s}>, "
                             "expected <EtherCATConfig>", root)
        config = self.child(root, "Config")
        image = config.find("ProcessImage")
        from ecatcfg.eni.contents import audit, dropped_init_cmds
        self._dropped = dropped_init_cmds(config)
        ignored: list[Unsupported] = []
        slave_els: list[Element] = []
        slaves: list[SlavePlan] = []
        passive: list[tuple[Element, PassiveSlave]] = []
        # No address, but a mailbox, InitCmds, process data or DC: an ESC slave whose
        # place is its order in the file (SOEM's sample ENI; SOEM's ENI converter,
        # scripts/eniconv.py, takes a missing AutoIncAddr as 1 - n for the n-th Slave).
        addressed = [(el, self.has_esc(el)) for el in config.iterchildren("Slave")]
        unaddressed = [el for el, has in addressed
                       if not has and self.needs_esc(el) is not None]
        self.placed_by_order([el for el, has in addressed if has] + unaddressed, unaddressed)
        for el, has in addressed:
            if has or el in unaddressed:
                slave_els.append(el)
                slaves.append(self.slave(el, position=None if has else len(slaves)))
            else:
                passive.append((el, self.passive(el, after=len(slaves))))
        self.hot_connect_groups(slave_els, slaves)
        self.passive_outside_groups(slave_els, slaves, passive)
        plan = NetworkPlan(
            master=self.master(self.child(config, "Master")),
            slaves=slaves,
            cyclic=[self.cyclic(el) for el in config.iterchildren("Cyclic")],
            process_image=ProcessImage() if image is None else self.process_image(image),
            version=root.get("Version"),
            unsupported=audit(config, ignored),
            ignored=ignored,
            passive=[p for _, p in passive],
        )
        plan.unsupported += self.copies_outside(plan)
        return plan

    # --- commands -------------------------------------------------------------------------

    def address(self, el: _Node) -> tuple[int | None, int | None, int | None]:
        """``(adp, ado, addr)``: ``(Adp?, Ado) | Addr``."""
        adp, ado, addr = (self.opt_int(el, "Adp", S16), self.opt_int(el, "Ado", U16),
                          self.opt_int(el, "Addr", S32))
        if adp is not None:
            adp &= 0xFFFF           # -1: the second slave's auto-increment address
        if addr is not None:
            addr &= 0xFFFFFFFF
        if ado is None and addr is None:
            raise self.error(f"<{el.tag!s}> has neither <Ado> nor <Addr>", el)
        return adp, ado, addr

    def payload(self, el: _Node) -> tuple[bytes | None, int]:
        """``(data, length)``: ``Data``, or ``DataLength`` zero bytes (eni-exports §2)."""
        data = self.opt_hex(el, "Data")
        if data is not None:
            if len(data) > MAX_DATAGRAM_DATA:
                where = el.find("Data")
                raise self.error(f"<Data> of {len(data)} bytes is more than one datagram "
                                 f"carries ({MAX_DATAGRAM_DATA})",
                                 el if where is None else where)
            return data, len(data)
        length = self.opt_int(el, "DataLength", DATAGRAM)
        if length is None:
            raise self.error(f"<{el.tag!s}> has neither <Data> nor <DataLength>", el)
        return None, length

    def init_cmd(self, element: Element) -> InitCmd:
        el = _Children(element)
        adp, ado, addr = self.address(el)
        data, length = self.payload(el)
        validate = el.find("Validate")
        return InitCmd(
            transitions=self.transitions(el),
            comment=self.opt_text(el, "Comment") or "",
            cmd=self.req_int(el, "Cmd", U8),
            length=length,
            adp=adp, ado=ado, addr=addr, data=data,
            cnt=self.opt_int(el, "Cnt", U16),
            retries=self.opt_int(el, "Retries", COUNT),
            validate=None if validate is None else self.validate(validate),
            requires=self.opt_text(el, "Requires"),
            before_slave=self.opt_bool(el, "BeforeSlave"),
            timeout=self.opt_int(el, "Timeout", COUNT),
        )

    def validate(self, el: Element) -> Validate:
        from ecatcfg.eni.compare import NAMES, compare_type
        kind = el.get("Type")
        compare = None if kind is None else compare_type(kind)
        if kind is not None and compare is None:
            raise self.error(f"<Validate Type={kind!r}>: not a compare type of ETG.2000 "
                             f"({NAMES})", el)
        return Validate(data=self.hex_bytes(self.child(el, "Data")),
                        mask=self.opt_hex(el, "DataMask"),
                        timeout=self.int_or(el, "Timeout", 0, COUNT),
                        compare=None if compare == "EQ" else compare)

    def init_cmds(self, parent: Element) -> list[InitCmd]:
        cmds = parent.find("InitCmds")
        return [] if cmds is None else [self.init_cmd(c) for c in cmds.iterchildren("InitCmd")
                                        if c not in self._dropped]

    # --- master ---------------------------------------------------------------------------

    def master(self, el: Element) -> MasterPlan:
        info = self.child(el, "Info")
        defaults = MasterPlan(name="")
        states = el.find("MailboxStates")
        return MasterPlan(
            name=self.opt_text(info, "Name") or "",
            destination=self.hex_or(info, "Destination", defaults.destination),
            source=self.hex_or(info, "Source", defaults.source),
            ether_type=self.hex_or(info, "EtherType", defaults.ether_type),
            mailbox_states=None if states is None else (self.uint32(states, "StartAddr"),
                                                         self.req_int(states, "Count", COUNT)),
            init_cmds=self.init_cmds(el),
        )

    # --- slaves ---------------------------------------------------------------------------

    def slave(self, el: Element, position: int | None = None) -> SlavePlan:
        """``position``: the place of a slave the file gives no address (see
        :meth:`placed_by_order`): station address ``FIRST_STATION_ADDRESS + position``, as
        compile numbers them."""
        info = self.child(el, "Info")
        pd = el.find("ProcessData")
        mailbox = el.find("Mailbox")
        dc = el.find("DC")
        hot = el.find("HotConnect")
        if position is None:
            phys = self.req_int(info, "PhysAddr", U16)
            auto = self.req_int(info, "AutoIncAddr", S16) & 0xFFFF             # -1 -> 65535
        else:
            phys, auto = FIRST_STATION_ADDRESS + position, -position & 0xFFFF
        return SlavePlan(
            name=self.opt_text(info, "Name") or "",
            phys_addr=phys,
            auto_inc_addr=auto,
            # EAS writes Physics as an attribute of Slave as well (eni-exports §8).
            physics=self.opt_text(info, "Physics") or el.get("Physics") or "YY",
            vendor_id=self.uint32(info, "VendorId"),
            product_code=self.uint32(info, "ProductCode"),
            revision=self.uint32(info, "RevisionNo"),
            serial_no=self.int_or(info, "SerialNo", 0, S32) & 0xFFFFFFFF,
            process_data=None if pd is None else self.process_data(pd),
            mailbox=None if mailbox is None else self.mailbox(mailbox),
            init_cmds=self.init_cmds(el),
            dc=None if dc is None else self.dc(dc),
            previous_ports=[self.previous_port(p) for p in el.iterchildren("PreviousPort")],
            hot_connect=None if hot is None else self.hot_connect(hot),
        )

    def has_esc(self, el: Element) -> bool:
        """Whether ``Info`` has the group ETG.2100 documents as "slave device has EtherCAT
        Slave Controller" (``PhysAddr``, ``AutoIncAddr``, ``Physics``, all or none): a
        slave without it is passive.  Part of the group is an error at ``Info``'s line."""
        info = self.child(el, "Info")
        present = [tag for tag in ("PhysAddr", "AutoIncAddr") if info.find(tag) is not None]
        if len(present) == 1:
            missing = "AutoIncAddr" if present == ["PhysAddr"] else "PhysAddr"
            raise self.error(f"<Info> has <{present[0]}> but no <{missing}>: a slave with an "
                             "ESC has both, a passive one neither", info)
        if not present and info.find("Physics") is not None:
            raise self.error("<Info> has <Physics> but no <PhysAddr> and <AutoIncAddr>: a "
                             "slave with an ESC has all three, a passive one none", info)
        return bool(present)

    def needs_esc(self, el: Element) -> tuple[Element, str] | None:
        """The first part of a slave that only an ESC can have (InitCmds, a mailbox,
        SyncManagers, PDOs or process image ranges, DC, identifying a hot-connect group)
        and what it is, or None: a passive terminal (TwinCAT's EL9011) has none."""
        pd = el.find("ProcessData")
        init_cmds = el.find("InitCmds")
        parts = [
            (pd[0] if pd is not None and len(pd) else None, "process data"),
            (init_cmds[0] if init_cmds is not None and len(init_cmds) else None, "InitCmds"),
            (el.find("Mailbox"), "a mailbox"),
            (el.find("DC"), "distributed clocks"),
            (el.find("HotConnect"), "a hot-connect group"),
        ]
        return next(((part, what) for part, what in parts if part is not None), None)

    def placed_by_order(self, elements: list[Element], unaddressed: list[Element]) -> None:
        """Slaves with what needs an ESC but without ``PhysAddr`` and ``AutoIncAddr`` (a
        hand-written ENI, as SOEM's sample) are placed by their order in the file, as
        SOEM's converter places them.  Beside slaves that do give an address that order
        may not be their place (a passive slave, a gap in the addresses): an error at the
        first of them, naming what needs the ESC."""
        if not unaddressed or len(unaddressed) == len(elements):
            return
        el = unaddressed[0]
        name = self.opt_text(self.child(el, "Info"), "Name") or ""
        found = self.needs_esc(el)
        assert found is not None
        part, what = found
        raise self.error(
            f"slave {name!r} has no <PhysAddr> and <AutoIncAddr> but has <{part.tag!s}> "
            f"({what} needs an EtherCAT Slave Controller), while other slaves give their "
            "address: its place on the line cannot be told; give it <PhysAddr> and "
            "<AutoIncAddr>", part)

    def passive(self, el: Element, after: int) -> PassiveSlave:
        """A slave without an ESC (:class:`PassiveSlave`): nothing :meth:`needs_esc`."""
        info = self.child(el, "Info")
        name = self.opt_text(info, "Name") or ""
        pd = el.find("ProcessData")
        return PassiveSlave(
            name=name,
            after=after,
            vendor_id=self.uint32(info, "VendorId"),
            product_code=self.uint32(info, "ProductCode"),
            revision=self.uint32(info, "RevisionNo"),
            serial_no=self.int_or(info, "SerialNo", 0, S32) & 0xFFFFFFFF,
            process_data=pd is not None,
            previous_ports=[self.previous_port(p) for p in el.iterchildren("PreviousPort")],
        )

    def passive_outside_groups(self, elements: list[Element], slaves: list[SlavePlan],
                               passive: list[tuple[Element, PassiveSlave]]) -> None:
        """A passive slave between a hot-connect group's head and its last member is an
        error: ETG.2100 does not say whether ``GroupMemberCnt`` counts it, and the two
        readings make different groups.  One after a group's last member is outside it."""
        for i, slave in enumerate(slaves):
            if slave.hot_connect is None:
                continue
            last = i + slave.hot_connect.member_count - 1
            for el, p in passive:
                if i < p.after <= last:
                    raise self.error(
                        f"passive slave {p.name!r} sits inside the hot-connect group of "
                        f"{slave.name!r} (line {elements[i].sourceline}): whether "
                        "<GroupMemberCnt> counts it is not defined; move it after the "
                        "group's last member", el)

    def hot_connect(self, element: Element) -> HotConnectPlan:
        """``HotConnect``: ``GroupMemberCnt`` and the ``IdentifyCmd`` commands (ETG.2100
        ``ECatCmdType``, read like an InitCmd); the count is checked against the slaves
        that follow by :meth:`hot_connect_groups`."""
        el = _Children(element)
        count = self.req_int(el, "GroupMemberCnt", I32)
        cmds = [self.init_cmd(c) for c in el.iterchildren("IdentifyCmd")]
        if not cmds:
            raise self.error("<HotConnect> has no <IdentifyCmd>: nothing tells the master "
                             "that the device at the group's place is its head", el)
        return HotConnectPlan(member_count=count, identify_cmds=cmds)

    def hot_connect_groups(self, elements: list[Element], slaves: list[SlavePlan]) -> None:
        """A group is its head and the slaves after it in the file, ``GroupMemberCnt`` in
        all: at least the head, no more slaves than the file has from the head on, and no
        slave in two groups (the master takes a group as absent or present as a whole)."""
        owner: dict[int, int] = {}            # slave index -> index of its group's head
        for i, (el, slave) in enumerate(zip(elements, slaves)):
            if slave.hot_connect is None:
                continue
            count_el = self.child(self.child(el, "HotConnect"), "GroupMemberCnt")
            count, left = slave.hot_connect.member_count, len(slaves) - i
            if count < 1:
                raise self.error(f"<GroupMemberCnt> {count}: a hot-connect group has at "
                                 "least its head", count_el)
            if count > left:
                raise self.error(f"<GroupMemberCnt> {count}: only {left} slave"
                                 f"{'s' if left != 1 else ''} from the group's head "
                                 f"{slave.name!r} to the end of the file", count_el)
            for member in range(i, i + count):
                if member in owner:
                    head = owner[member]
                    raise self.error(
                        f"the hot-connect group of {slave.name!r} takes slave "
                        f"{slaves[member].name!r}, which is already in the group of "
                        f"{slaves[head].name!r} (line {elements[head].sourceline}); a slave "
                        "belongs to one group", count_el)
                owner[member] = i

    def bit_range(self, el: Element) -> BitRange:
        return BitRange(self.req_int(el, "BitStart", IMAGE_BITS),
                        self.req_int(el, "BitLength", IMAGE_BITS))

    def process_data(self, el: Element) -> ProcessData:
        return ProcessData(
            send=[self.bit_range(s) for s in el.iterchildren("Send")],
            recv=[self.bit_range(r) for r in el.iterchildren("Recv")],
            sms=self.sms(el),
            pdos=self.pdos(el),
        )

    def sms(self, pd: Element) -> list[SmSettings]:
        """``Sm0``..``Sm3``, each at most once (ETG.2100 ``ProcessData``: a sequence of
        optional elements): two settings for one SyncManager leave the master no
        single size, start address or PDO list to write."""
        result = []
        for number in range(4):
            els = list(pd.iterchildren(f"Sm{number}"))
            if len(els) > 1:
                raise self.error(f"<Sm{number}> given again (first at line {els[0].sourceline})"
                                 ": a SyncManager has one setting", els[1])
            result += [self.sm(el, number) for el in els]
        return result

    def pdos(self, pd: Element) -> list[PdoDesc]:
        """``RxPdo``/``TxPdo``; one index described twice is an error: the PDO's entries
        (the slave's mapping object, ETG.1000.6 0x1600/0x1A00) would be two different
        lists, and which one the master writes would depend on their order."""
        result: list[PdoDesc] = []
        seen: dict[int, Element] = {}
        for el in pd.iterchildren("RxPdo", "TxPdo"):
            pdo = self.pdo(el)
            first = seen.setdefault(pdo.index, el)
            if first is not el:
                raise self.error(f"PDO 0x{pdo.index:04X} described again (first at line "
                                 f"{first.sourceline}): a PDO has one list of entries", el)
            result.append(pdo)
        return result

    def sm(self, el: Element, number: int) -> SmSettings:
        return SmSettings(
            number=number,
            type=self.opt_text(el, "Type") or "",
            start_address=self.req_int(el, "StartAddress", U16),
            control_byte=self.req_int(el, "ControlByte", U8),
            enable=self.boolean(self.child(el, "Enable")),
            pdos=[self.number(p, U16) for p in el.iterchildren("Pdo")],
            min_size=self.opt_int(el, "MinSize", U16),
            max_size=self.opt_int(el, "MaxSize", U16),
            default_size=self.opt_int(el, "DefaultSize", U16),
            virtual=self.opt_bool(el, "Virtual"),
            watchdog=self.opt_int(el, "Watchdog", U16),
        )

    def pdo(self, el: Element) -> PdoDesc:
        return PdoDesc(
            direction="rx" if el.tag == "RxPdo" else "tx",
            index=self.req_int(el, "Index", U16),
            name=self.opt_text(el, "Name") or "",        # the first Name (one per language)
            entries=[self.entry(e) for e in el.iterchildren("Entry")],
            sm=self.attr_int(el, "Sm", SM_NUMBER),
            fixed=bool(self.attr_bool(el, "Fixed")),
            mandatory=bool(self.attr_bool(el, "Mandatory")),
            virtual=bool(self.attr_bool(el, "Virtual")),
            excludes=[self.number(x, U16) for x in el.iterchildren("Exclude")],
        )

    def entry(self, el: Element) -> PdoEntryDesc:
        return PdoEntryDesc(
            index=self.req_int(el, "Index", U16),
            subindex=self.int_or(el, "SubIndex", 0, U8),
            bit_len=self.req_int(el, "BitLen", U16),
            name=self.opt_text(el, "Name") or "",
            data_type=self.opt_text(el, "DataType"),
        )

    def mailbox_area(self, el: Element) -> MailboxArea:
        return MailboxArea(self.req_int(el, "Start", U16), self.req_int(el, "Length", DATAGRAM))

    def mailbox_recv(self, el: Element) -> Element:
        """``Recv`` (ETG.2100), or ``Receive``, as SOEM's hand-written sample ENI spells it;
        not both."""
        spelled = el.find("Receive")
        if spelled is None:
            return self.child(el, "Recv")
        if el.find("Recv") is not None:
            raise self.error("<Mailbox> has both <Recv> and <Receive>: one SM1 area, "
                             "named once", spelled)
        return spelled

    def mailbox(self, el: Element) -> MailboxPlan:
        recv = self.mailbox_recv(el)
        boot = el.find("BootStrap")
        coe, eoe, aoe, soe = (el.find(tag) for tag in ("CoE", "EoE", "AoE", "SoE"))
        foe = el.find("FoE")
        return MailboxPlan(
            send=self.mailbox_area(self.child(el, "Send")),
            recv=self.mailbox_area(recv),
            protocols=[self.text(p).strip() for p in el.iterchildren("Protocol")],
            poll_time=self.opt_int(recv, "PollTime", COUNT),
            status_bit_addr=self.opt_int(recv, "StatusBitAddr", S32),
            bootstrap_send=None if boot is None else self.mailbox_area(self.child(boot, "Send")),
            bootstrap_recv=None if boot is None else self.mailbox_area(self.child(boot, "Recv")),
            coe_init_cmds=[] if coe is None else self.coe_init_cmds(coe),
            coe_profiles=[] if coe is None else self.coe_profiles(coe),
            data_link_layer=self.attr_bool(el, "DataLinkLayer"),
            eoe_init_cmds=[] if eoe is None else self.eoe_init_cmds(eoe),
            soe_init_cmds=[] if soe is None else self.soe_init_cmds(soe),
            foe_init_cmds=[] if foe is None else self.foe_init_cmds(foe),
            aoe_net_id=None if aoe is None else self.opt_text(aoe, "NetId"),
        )

    def eoe_init_cmds(self, eoe: Element) -> list[EoeInitCmd]:
        cmds = eoe.find("InitCmds")
        if cmds is None:
            return []
        return [self.eoe_init_cmd(c) for c in cmds.iterchildren("InitCmd")
                if c not in self._dropped]

    def eoe_init_cmd(self, element: Element) -> EoeInitCmd:
        """ETG.2100 ``MailboxCmdType``; ``Data`` must be a set IP parameter request in one
        of the encodings real files use (``ecatcfg.eoe.decode_init_data``)."""
        from ecatcfg.eoe import decode_init_data

        el = _Children(element)
        data_el = self.child(el, "Data")
        data = self.hex_bytes(data_el)
        try:
            decode_init_data(data)
        except ValueError as exc:
            raise self.error(f"EoE <Data>: {exc}", data_el) from None
        return EoeInitCmd(
            transitions=self.transitions(el),
            comment=self.opt_text(el, "Comment") or "",
            data=data,
            timeout=self.int_or(el, "Timeout", 0, COUNT),
            disabled=bool(self.opt_bool(el, "Disabled")),
            fixed=bool(self.attr_bool(el, "Fixed")),
        )

    def soe_init_cmds(self, soe: Element) -> list[SoeInitCmd]:
        cmds = soe.find("InitCmds")
        if cmds is None:
            return []
        return [self.soe_init_cmd(c) for c in cmds.iterchildren("InitCmd")
                if c not in self._dropped]

    def soe_init_cmd(self, element: Element) -> SoeInitCmd:
        """ETG.2100 ``Mailbox/SoE/InitCmds/InitCmd``: an SoE service-channel request.
        The OpCode is read as written (what apply refuses is ``eni/contents.py``'s)."""
        el = _Children(element)
        return SoeInitCmd(
            transitions=self.transitions(el),
            comment=self.opt_text(el, "Comment") or "",
            idn=self.req_int(el, "IDN", U16),
            data=self.hex_or(el, "Data", b""),
            op_code=self.req_int(el, "OpCode", SOE_OPCODE),
            drive_no=self.req_int(el, "DriveNo", SOE_DRIVE),
            elements=self.req_int(el, "Elements", U8),
            attribute=self.uint32(el, "Attribute"),
            timeout=self.int_or(el, "Timeout", 0, COUNT),
            disabled=bool(self.opt_bool(el, "Disabled")),
            fixed=bool(self.attr_bool(el, "Fixed")),
        )

    def foe_init_cmds(self, foe: Element) -> list[FoeInitCmd]:
        """ETG.2100 ``MailboxCmdType``; what the FoE message in ``Data`` may be is
        ``eni/contents.py``'s (a refused one is left out of the plan)."""
        cmds = foe.find("InitCmds")
        if cmds is None:
            return []
        out = []
        for element in cmds.iterchildren("InitCmd"):
            if element in self._dropped:
                continue
            el = _Children(element)
            out.append(FoeInitCmd(
                transitions=self.transitions(el),
                comment=self.opt_text(el, "Comment") or "",
                data=self.hex_bytes(self.child(el, "Data")),
                timeout=self.int_or(el, "Timeout", 0, COUNT),
                disabled=bool(self.opt_bool(el, "Disabled")),
                fixed=bool(self.attr_bool(el, "Fixed")),
            ))
        return out

    def coe_init_cmds(self, coe: Element) -> list[CoeInitCmd]:
        cmds = coe.find("InitCmds")
        if cmds is None:
            return []
        return [self.coe_init_cmd(c) for c in cmds.iterchildren("InitCmd")
                if c not in self._dropped]

    def coe_init_cmd(self, element: Element) -> CoeInitCmd:
        el = _Children(element)
        return CoeInitCmd(
            transitions=self.transitions(el),
            comment=self.opt_text(el, "Comment") or "",
            index=self.req_int(el, "Index", U16),
            subindex=self.int_or(el, "SubIndex", 0, U8),
            data=self.hex_or(el, "Data", b""),
            ccs=self.int_or(el, "Ccs", 1, U8),
            timeout=self.int_or(el, "Timeout", 0, COUNT),
            complete_access=bool(self.attr_bool(el, "CompleteAccess")),
            fixed=bool(self.attr_bool(el, "Fixed")),
            disabled=bool(self.opt_bool(el, "Disabled")),
        )

    def coe_profiles(self, coe: Element) -> list[tuple[int, str | None]]:
        profile = coe.find("Profile")
        if profile is None:
            return []
        return [(self.req_int(ch, "ProfileNo", S32), self.opt_text(ch, "AddInfo"))
                for ch in profile.iterchildren("ChannelInfo")]

    def dc(self, el: Element) -> DcPlan | None:
        """``None`` for a DC element that only says the slave *could* be reference clock
        (``PotentialReferenceClock`` alone: EC-Engineer, slaves with DC unused)."""
        if all(el.find(tag) is None for tag in _DC_VALUES):
            return None
        return DcPlan(
            reference_clock=bool(self.opt_bool(el, "ReferenceClock")),
            cycle_time0=self.int_or(el, "CycleTime0", 0, S32) & 0xFFFFFFFF,
            cycle_time1=self.int_or(el, "CycleTime1", 0, S32) & 0xFFFFFFFF,
            shift_time=self.int_or(el, "ShiftTime", 0, I32),
        )

    def previous_port(self, el: Element) -> PreviousPort:
        # Selected is xs:int in the 2011 schema; TwinCAT writes "true" (eni-exports §1).
        return PreviousPort(port=self.text(self.child(el, "Port")).strip(),
                            phys_addr=self.opt_int(el, "PhysAddr", U16),
                            selected=self.attr_bool(el, "Selected"))

    # --- cyclic frames and process image --------------------------------------------------

    def cyclic(self, el: Element) -> Cyclic:
        return Cyclic(frames=[self.frame(f) for f in el.iterchildren("Frame")],
                      cycle_time=self.opt_int(el, "CycleTime", COUNT),
                      comment=self.opt_text(el, "Comment"))

    def frame(self, el: Element) -> Frame:
        cmds = [self.cyclic_cmd(c) for c in el.iterchildren("Cmd")]
        # A Frame is one Ethernet frame: its datagrams must fit one frame's payload.
        size = frame_bytes([c.length for c in cmds])
        if size > FRAME_PAYLOAD:
            raise self.error(f"<Frame> of {len(cmds)} commands needs {size} bytes, more than "
                             f"one Ethernet frame carries ({FRAME_PAYLOAD})", el)
        return Frame(cmds=cmds, comment=self.opt_text(el, "Comment"))

    def cyclic_cmd(self, element: Element) -> CyclicCmd:
        el = _Children(element)
        adp, ado, addr = self.address(el)
        data, length = self.payload(el)
        return CyclicCmd(
            states=[self.text(s).strip() for s in el.iterchildren("State")],
            comment=self.opt_text(el, "Comment") or "",
            cmd=self.req_int(el, "Cmd", U8),
            length=length,
            adp=adp, ado=ado, addr=addr, data=data,
            cnt=self.opt_int(el, "Cnt", U16),
            input_offs=self.int_or(el, "InputOffs", 0, IMAGE),
            output_offs=self.int_or(el, "OutputOffs", 0, IMAGE),
            copy_infos=[self.copy_info(c) for c in element.iterfind("CopyInfos/CopyInfo")],
        )

    def copy_info(self, el: Element) -> CopyInfo:
        copy = CopyInfo(src_bit_offs=self.req_int(el, "SrcBitOffs", IMAGE_BITS),
                        dst_bit_offs=self.req_int(el, "DstBitOffs", IMAGE_BITS),
                        bit_size=self.req_int(el, "BitSize", VARIABLE_BITS))
        self._copy_lines[id(copy)] = el.sourceline
        return copy

    def copies_outside(self, plan: NetworkPlan) -> list[Unsupported]:
        """Copies whose source or destination is outside the images the master keeps
        (:meth:`NetworkPlan.image_bytes`): no master can carry them out faithfully.  They
        leave the plan (a skipping apply does not perform them) and are refused by name."""
        inputs, outputs = plan.image_bytes()
        found = []
        for cyclic in plan.cyclic:
            for frame in cyclic.frames:
                for cmd in frame.cmds:
                    kept = []
                    for copy in cmd.copy_infos:
                        if copy.fits(inputs, outputs):
                            kept.append(copy)
                            continue
                        found.append(Unsupported(
                            COPY_ELEMENT, f"a slave-to-slave copy outside the process image "
                            f"({copy.describe()}; the images have {inputs} input and "
                            f"{outputs} output bytes)", self._copy_lines.get(id(copy))))
                    cmd.copy_infos = kept
        return found

    def process_image(self, el: Element) -> ProcessImage:
        image = ProcessImage()
        inputs, outputs = el.find("Inputs"), el.find("Outputs")
        if inputs is not None:
            image.inputs_size = self.req_int(inputs, "ByteSize", IMAGE)
            # Not bounded by ByteSize: TwinCAT writes the status variables its master keeps
            # on the host after the inputs image (InfoData.ChangeCount at bit 12288 of a
            # 1536-byte image); nothing is written there, reading it is the API's business.
            image.inputs = [self.variable(v) for v in inputs.iterchildren("Variable")]
        if outputs is not None:
            image.outputs_size = self.req_int(outputs, "ByteSize", IMAGE)
            image.outputs = self.variables(outputs, image.outputs_size)
        return image

    def variables(self, part: Element, byte_size: int) -> list[Variable]:
        """The ``Variable`` list of ``Outputs``: each within its ``ByteSize`` (ETG.2100: the
        size of the output image), the bytes the master sends and the Network API writes;
        a variable past the end names no bits of the image the cyclic commands carry."""
        result = []
        for el in part.iterchildren("Variable"):
            var = self.variable(el)
            end = var.bit_offs + var.bit_size
            if end > 8 * byte_size:
                raise self.error(
                    f"variable {var.name!r} (<BitOffs> {var.bit_offs}, <BitSize> "
                    f"{var.bit_size}) ends at bit {end}, past the {part.tag!s} image of "
                    f"<ByteSize> {byte_size} ({8 * byte_size} bits)", el)
            result.append(var)
        return result

    def variable(self, el: Element) -> Variable:
        return Variable(name=self.text(self.child(el, "Name")),
                        bit_size=self.req_int(el, "BitSize", VARIABLE_BITS),
                        bit_offs=self.req_int(el, "BitOffs", IMAGE_BITS),
                        data_type=self.opt_text(el, "DataType"),
                        comment=self.opt_text(el, "Comment"))
