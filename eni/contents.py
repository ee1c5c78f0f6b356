"""What an ENI may contain, and what ecatcfg does with each part: the ENI reader's explicit list.

Every element below ``<Config>`` that can change what a master does is listed here, in
one of three kinds:

- **read**: the plan holds it and ``apply`` does what it says;
- **accepted**: it asks nothing of the master at start-up (an address, a description, the
  master's own host-side settings), or it holds the one value that asks nothing; the
  reason is given;
- **refused**: it configures the master's behaviour toward a slave and ``apply`` does not
  implement it.  The reader records it as an :class:`~ecatcfg.eni.plan.Unsupported` in the
  plan (with its line, slave and how many commands would be lost), and ``apply`` and the
  ``Network`` refuse the plan before anything is written to the bus, unless told to skip
  it (``--skip-unsupported``).

The contexts named in :data:`CONTENTS` are *closed*: a child element not listed there is
refused as unknown, since nothing tells whether it changes what the master must do, and
so is an attribute of a child that is not listed as ``Tag@Name`` (``Slave@HotPlug``).
What is inside a part without a context of its own (``within`` None) is covered by that
part, whatever it is: a description whose effect reaches the wire only through InitCmds
(``ProcessData``, ``ProcessImage``, the master's ``Info``), a part read or accepted as a
whole (``Identification``), or refused as a whole (``VoE``).  Outside
``<Config>`` is open too (:data:`OPEN`: vendor data such as Elmo Application Studio's
``ElmoSpecialResources``), but for :data:`ROOT`.  Every element and attribute of the
ETG.2100 schema has its part (:func:`covering`; a test parses the schema).
``docs/runtime.md`` shows this list as a table; a test keeps the two equal.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

from lxml import etree

from ecatcfg.eni.plan import NetworkPlan, Unsupported
from ecatcfg.errors import EcatcfgError, location
from ecatcfg.esc import FOE_HEADER, LOGICAL_CMDS, TRANSITION_RULES, FoeOpCode, Transition
from ecatcfg.esi import vocabulary
from ecatcfg.esi.idn import WRITE_REQUEST
from ecatcfg.esi.values import SPELLABLE, parse_bool, parse_int
from ecatcfg.record import record

Element = etree._Element
Kind = Literal["read", "accepted", "refused"]
# A check looks at the element and says what apply would not do ("" when all is well).
Check = Callable[[Element], str]


@record(frozen=True)
class Part:
    """One element of a context: its kind, what apply does with it (or why it is accepted,
    or what it would ask of the master), and where the walk goes on from it."""

    kind: Kind
    text: str
    within: str | None = None          # the context of its children, if it is checked
    check: Check | None = None         # a condition on the element (kind "accepted"/"read")
    counts: bool = False               # refused: count its commands as commands lost ...
    empty_ok: bool = False             # ... and accept it when it holds none (<FoE/>)


def _read(text: str, within: str | None = None, check: Check | None = None) -> Part:
    return Part("read", text, within, check)


def _accepted(text: str, check: Check | None = None) -> Part:
    return Part("accepted", text, None, check)


def _refused(text: str, counts: bool = False, empty_ok: bool = False) -> Part:
    return Part("refused", text, counts=counts, empty_ok=empty_ok)


# -- conditions ---------------------------------------------------------------------------

def _text(el: Element) -> str:
    return "".join(el.itertext()).strip()


def _empty(el: Element) -> str:
    return "" if len(el) == 0 and not _text(el) else f"<{el.tag!s}> is not empty"


def _zero_or_absent(text: str | None) -> bool:
    if text is None or not text.strip():
        return True
    try:
        return parse_int(text) == 0
    except ValueError:
        try:
            return not parse_bool(text)
        except ValueError:
            return False


def _zero(el: Element) -> str:
    return "" if _zero_or_absent(_text(el)) else f"<{el.tag!s}> {_text(el)!r}"


def _all_zero_bytes(el: Element) -> str:
    text = _text(el)
    return "" if set(text) <= {"0"} else f"<{el.tag!s}> {text}"


def _identification(el: Element) -> str:
    enabled = el.get("EnableIdentification")
    if enabled is None or _zero_or_absent(enabled):
        return ""
    ado = el.findtext("Ado")
    return (f"explicit device identification (<Identification EnableIdentification="
            f"{enabled!r}>, value {el.get('Value')!r} at {ado})")


def _zero_attribute(name: str, what: str) -> Check:
    """The attribute ``name`` is absent or 0; otherwise it asks for ``what``."""
    def check(el: Element) -> str:
        value = el.get(name)
        return "" if _zero_or_absent(value) else f"{what} (<{el.tag!s} {name}={value!r}>)"
    return check


def _master_time_as_ref(el: Element) -> str:
    text = el.findtext("MasterTimeAsRef")
    return "" if _zero_or_absent(text) else \
        "the master's clock as the DC reference (<DC><MasterTimeAsRef>)"


def _frame_size(el: Element) -> str:
    try:
        size = parse_int(_text(el), -SPELLABLE, SPELLABLE)
    except ValueError:
        return f"<MaxFrameSize> {_text(el).strip()[:24]!r}"
    if size >= 1514:
        return ""
    if size < 0:        # shown as written: thousands of digits cannot be str()-ed (4,300)
        return f"<MaxFrameSize> {_text(el).strip()[:24]!r}: a negative frame size"
    return f"frames of at most {size} bytes (<MaxFrameSize>)"


# -- the list -----------------------------------------------------------------------------

_INIT_CMD = "InitCmds/InitCmd"   # ECatCmdType: register commands of the master and slaves
_COMMAND = "a field of the command, replayed as written"
_FIXED = ("the configurator may not change the command (ETG.2100): kept in the plan and "
          "written back, no effect on the wire")

CONTENTS: dict[str, dict[str, Part]] = {
    "Config": {
        "Master": _read("the master's frame addresses and InitCmds", "Config/Master"),
        "Slave": _read("one slave", "Config/Slave"),
        "Slave@HotPlug": _accepted("when 0: the slave is always there (Elmo Application "
                                   "Studio)", _zero_attribute("HotPlug", "hot plug")),
        "Slave@Physics": _accepted("the slave's ports' physical layer, as Info/Physics: "
                                   "a description"),
        **{f"Slave@{name}": _accepted("Elmo Application Studio: the line segment of the "
                                      "slave, a description; its place is Info/AutoIncAddr")
           for name in ("Segment", "SegmentSubIndex")},
        "Cyclic": _read("cyclic frames, run from SAFEOP on", "Config/Cyclic"),
        "ProcessImage": _read("the variables of the process image (Network API names)"),
        "ExternalDrivers": _accepted("Elmo Application Studio: when empty, no driver to "
                                     "load", _empty),
    },
    "Config/Master": {
        "Info": _read("name, destination and source MAC, EtherType"),
        "MailboxStates": _read("the mailbox-state bits: apply polls the bits of the "
                               "slaves whose StatusBitAddr the area holds with one LRD "
                               "(eni/mailbox_states.py), the others' SM1 status byte "
                               "(0x080D)"),
        "EoE": _accepted("the master's own EoE switch (ports, frames, MAC table): no "
                         "command to a slave"),
        "InitCmds": _read("replayed before (BeforeSlave) or after the slaves' commands",
                          "InitCmds"),
        # Elmo Application Studio's master settings (docs/eni-exports.md §8).
        "NIC": _accepted("the interface name: apply's --iface chooses it"),
        "RNIC": _accepted("when empty: no second interface (cable redundancy)", _empty),
        "MaxFrameSize": _accepted("1514 or more: apply's frames are at most 1514 bytes",
                                  _frame_size),
        "SeparateIOUpdate": _accepted("when 0: inputs and outputs in the frames the ENI "
                                      "lists", _zero),
        "CycleTime": _accepted("the master's cycle; apply cycles at the Cyclic CycleTime, "
                               "else the DC SYNC0 cycle (equal in the files seen)"),
        "MBCycleTime": _accepted("how often the Elmo master polls mailboxes; apply polls "
                                 "a mailbox while it waits for an answer"),
        "InitialMasterState": _accepted("the state the Elmo master starts in; apply goes "
                                        "to its --state"),
        "AutoRecoveryTimeout": _accepted("when the Elmo master restarts a slave that "
                                         "dropped out; nothing at start-up"),
        "ProcessImageUpdatePeriod": _accepted("the Elmo master's host-side image copy"),
        "StatisticsUpdatePeriod": _accepted("the Elmo master's host-side statistics"),
        "DCUserShiftTime": _accepted("the Elmo master's send time within the cycle; the "
                                     "slaves' SYNC shift is their DC ShiftTime"),
        "DC": _accepted("the Elmo master's DC mode, unless the master's clock is the "
                        "reference (MasterTimeAsRef): apply follows the reference slave",
                        _master_time_as_ref),
    },
    "InitCmds": {
        "InitCmd": _read("a register command", _INIT_CMD),
    },
    _INIT_CMD: {
        **{tag: _read(_COMMAND) for tag in (
            "Transition", "BeforeSlave", "Comment", "Requires", "Cmd", "Adp", "Ado", "Addr",
            "Data", "DataLength", "Cnt", "Retries", "Timeout")},
        "Validate": _read("the read's check, polled until it passes", "InitCmd/Validate"),
        "Validate@Type": _read("how the read is compared with Data: the compare types of "
                               "ETG.2000's revision check (EQ, EQ_OR_G, LW_EQ, HW_EQ, "
                               "LW_EQ_HW_EQ_OR_G, HW_EQ_LW_EQ_OR_G; eni/compare.py)"),
    },
    # A check: what else it held could change it (a Type written as an element).
    "InitCmd/Validate": {tag: _read("what the read is checked against, under the mask, "
                                    "until the timeout") for tag in (
        "Data", "DataMask", "Timeout")},
    "Config/Slave": {
        "Info": _read("identity, station and auto-increment address", "Slave/Info"),
        "ProcessData": _read("SyncManagers and PDOs, as a description: the SM and FMMU "
                             "writes are InitCmds"),
        "Mailbox": _read("SM0/SM1 and the mailbox protocols", "Slave/Mailbox"),
        "Mailbox@DataLinkLayer": _read("the mailbox data link layer (repeat and counter "
                                       "handling), kept in the plan"),
        "InitCmds": _read("replayed transition by transition", "InitCmds"),
        "PreviousPort": _read("where the slave is connected (the tree is checked port by "
                              "port)", "Slave/PreviousPort"),
        "PreviousPort@Selected": _read("which of the slave's possible previous ports is "
                                       "the connected one"),
        "DC": _read("SYNC cycle and shift; DC set-up before PREOP->SAFEOP", "Slave/DC"),
        "HotConnect": _read("a hot-connect group: the head and the slaves after it may be "
                            "absent, the rest runs; the group joins when its head answers "
                            "its IdentifyCmds", "Slave/HotConnect"),
    },
    "Slave/PreviousPort": {
        "Port": _read("the port of the previous slave this one hangs on (checked)"),
        "PhysAddr": _read("the previous slave's station address"),
        "DeviceId": _accepted("the previous slave's device ID: a description; the tree is "
                              "checked by positions and ports"),
    },
    "Slave/HotConnect": {
        "GroupMemberCnt": _read("the head and the slaves after it in the file, this many "
                                "in all"),
        "IdentifyCmd": _read("a command that recognises the head (its station alias or "
                             "ID register), sent where the head is expected", _INIT_CMD),
    },
    "Slave/Info": {
        **{tag: _read("checked against the slave found at the position") for tag in (
            "VendorId", "ProductCode", "RevisionNo", "SerialNo")},
        **{tag: _read("the slave's name and addresses") for tag in (
            "Name", "PhysAddr", "AutoIncAddr", "Physics")},
        **{tag: _accepted("a description") for tag in (
            "ProductRevision", "NameInResource", "ProductName", "RevisionReal")},
        "NameInResource@DSType": _accepted("Elmo Application Studio: the kind of name, a "
                                           "description"),
        "Identification": _accepted("when EnableIdentification is false; otherwise the "
                                    "master would check an ID register first",
                                    _identification),
        **{f"Identification@{name}": _accepted("part of the Identification rule above")
           for name in ("EnableIdentification", "Value")},
    },
    "Slave/Mailbox": {
        "Send": _read("SM0: where requests are written"),
        "Recv": _read("SM1: where answers are read"),
        "Receive": _read("SM1, as SOEM's hand-written sample ENI names Recv"),
        "BootStrap": _accepted("the mailbox for BOOT: apply does not go to BOOT"),
        "Protocol": _accepted("the protocols the slave speaks: a description"),
        "CoE": _read("SDO downloads (and uploads) per transition", "Mailbox/CoE"),
        "EoE": _read("set IP parameter requests per transition", "Mailbox/EoE"),
        "AoE": _read("the slave's AMS NetId", "Mailbox/AoE"),
        "SoE": _read("SoE writes of drive parameters (IDNs) per transition", "Mailbox/SoE"),
        # Without (enabled) InitCmds these only say the protocol is there: nothing is lost.
        "FoE": _read("FoE read requests per transition", "Mailbox/FoE"),
        "VoE": _refused("VoE InitCmds (vendor-specific mailbox messages)", True, True),
    },
    "Mailbox/CoE": {
        "InitCmds": _read("SDO downloads (and uploads)", "CoE/InitCmds"),
        "Profile": _accepted("the device profile (CiA 402 ...): a description"),
    },
    "CoE/InitCmds": {
        "InitCmd": _read("one SDO transfer", "CoE/InitCmds/InitCmd"),
        "InitCmd@CompleteAccess": _read("the whole object in one transfer (complete "
                                        "access)"),
        "InitCmd@Fixed": _read(_FIXED),
    },
    "CoE/InitCmds/InitCmd": {
        **{tag: _read(_COMMAND) for tag in (
            "Transition", "Comment", "Timeout", "Ccs", "Index", "SubIndex", "Data",
            "Disabled")},
        "IndexType": _accepted("Elmo Application Studio: who made the command, like the "
                               "Fixed attribute"),
        # ETG.2000 (ESI) CoE InitCmds carry it, and a configurator may copy it along.
        "Data@AdaptAutomatically": _accepted("the configurator may adapt Data to the PDO "
                                             "configuration; the file holds the adapted "
                                             "data, sent as written"),
    },
    "Mailbox/EoE": {"InitCmds": _read("set IP parameter requests", "EoE/InitCmds")},
    "EoE/InitCmds": {
        "InitCmd": _read("one EoE request", "EoE/InitCmds/InitCmd"),
        "InitCmd@Fixed": _read(_FIXED),
    },
    "EoE/InitCmds/InitCmd": {tag: _read(_COMMAND) for tag in (
        "Transition", "Comment", "Timeout", "Data", "Disabled")},
    "Mailbox/SoE": {"InitCmds": _read("SoE service-channel requests", "SoE/InitCmds")},
    "SoE/InitCmds": {
        "InitCmd": _read("one SoE request", "SoE/InitCmds/InitCmd"),
        "InitCmd@Fixed": _read(_FIXED),
    },
    "SoE/InitCmds/InitCmd": {
        **{tag: _read(_COMMAND) for tag in (
            "Transition", "Comment", "Timeout", "DriveNo", "IDN", "Elements", "Attribute",
            "Data", "Disabled")},
        "OpCode": _read("3, a write request (the schema's \"service channel write req\"); "
                        "another OpCode is refused"),
    },
    "Mailbox/FoE": {"InitCmds": _read("FoE requests", "FoE/InitCmds")},
    "FoE/InitCmds": {
        "InitCmd": _read("one FoE read request, the file read to its end (other FoE "
                         "requests are refused by name)", "FoE/InitCmds/InitCmd"),
        "InitCmd@Fixed": _read(_FIXED),
    },
    "FoE/InitCmds/InitCmd": {tag: _read(_COMMAND) for tag in (
        "Transition", "Comment", "Timeout", "Data", "Disabled")},
    "Mailbox/AoE": {
        "NetId": _accepted("an address, no command"),
        "InitCmds": _refused("AoE InitCmds (ADS requests)", True, True),
    },
    "Slave/DC": {
        **{tag: _read("SYNC0/1 set-up") for tag in (
            "ReferenceClock", "CycleTime0", "CycleTime1", "ShiftTime")},
        "PotentialReferenceClock": _accepted("could be the reference clock: a "
                                             "description"),
    },
    "Config/Cyclic": {
        "Comment": _accepted("a description"),
        "CycleTime": _read("the cycle time (µs)"),
        "Priority": _accepted("the task priority on the configurator's host"),
        "TaskId": _accepted("the task on the configurator's host"),
        "Frame": _read("one Ethernet frame per cycle", "Cyclic/Frame"),
        **{f"Frame@{name}": _accepted("when 0: the frame goes every cycle (Elmo "
                                      "Application Studio)", _zero_attribute(
                                          name, "a frame sent on its own cycle"))
           for name in ("CycleTimeFactor", "CycleTimeShiftFactor")},
    },
    "Cyclic/Frame": {
        "Comment": _accepted("a description"),
        "Cmd": _read("one datagram", "Frame/Cmd"),
    },
    "Frame/Cmd": {
        **{tag: _read(_COMMAND) for tag in (
            "State", "Comment", "Cmd", "Adp", "Ado", "Addr", "Data", "DataLength", "Cnt",
            "InputOffs", "OutputOffs")},
        "CopyInfos": _read("slave-to-slave copies, each cycle (a copy outside the process "
                           "image is refused by the reader)", "Cmd/CopyInfos"),
        # Elmo Application Studio (docs/eni-exports.md §8).
        "MaxErrors": _accepted("how many working-counter errors the Elmo master "
                               "tolerates; apply counts them and goes on"),
        "OwnerPhysAddr": _accepted("the slave the datagram is for: a description"),
        **{tag: _accepted("when all zero: the image apply starts from", _all_zero_bytes)
           for tag in ("InputDefaultData", "InputDefaultDataMask", "OutputDefaultData",
                       "OutputDefaultDataMask")},
    },
    # -- slave-to-slave copies (ETG.2100 CopyInfosType) --
    "Cmd/CopyInfos": {
        "CopyInfo": _read("one copy: input bits to output bits after a valid receive",
                          "CopyInfos/CopyInfo"),
    },
    "CopyInfos/CopyInfo": {tag: _read("where from, where to, how many bits")
                           for tag in ("SrcBitOffs", "DstBitOffs", "BitSize")},
}

def _complete_access_elsewhere(el: Element) -> str:
    value = el.get("CompleteAccess")
    return "" if _zero_or_absent(value) else (
        f"complete access on <{el.tag!s}> (<{el.tag!s} CompleteAccess={value!r}>): only a "
        "CoE SDO transfer can be one")


# Attributes with one meaning wherever they appear (ETG.2000/ETG.2100 use them on more
# elements than the 1.3 schema shows: TwinCAT writes AdaptAutomatically on a CoE InitCmd,
# ETG.2000 on its Data).  A context's own ``Tag@Name`` comes first (``InitCmd@CompleteAccess``
# of a CoE InitCmd is read there); these answer for the attribute anywhere else.
ANYWHERE: dict[str, Part] = {
    "AdaptAutomatically": _accepted("the configurator may adapt the data to the PDO "
                                    "configuration; the file holds the adapted data, sent "
                                    "as written"),
    "Fixed": _accepted(_FIXED),
    "Selected": _accepted("which of several alternatives is in use: the file holds the "
                          "chosen one"),
    "CompleteAccess": _accepted("when false: an ordinary access",
                                _complete_access_elsewhere),
}

# Open contexts: what is inside is accepted whatever it is (with this reason).
OPEN = {
    "EtherCATConfig": "elements outside <Config> (ElmoSpecialResources, ResID, Manufacturer "
                      "...): vendor data; ETG.2100 puts all the master does in <Config>",
}

# Where a child's context starts: root -> Config.
ROOT_CONTEXT = "Config"
# The root element's own parts (the rest of the root is open, OPEN).
ROOT: dict[str, Part] = {
    "Config": _read("all the master does", ROOT_CONTEXT),
    "@Version": _read("the ETG.2100 version the file follows, kept in the plan"),
}


def covering(path: list[str]) -> Part | None:
    """The part that says what apply does with the element or attribute at ``path``
    below the root (``["Config", "Slave", "Mailbox", "@DataLinkLayer"]``), ``None`` when
    the list has none.  An attribute is listed as ``Tag@Name`` next to its element; what
    is inside a part without a context of its own is covered by that part."""
    parts = ROOT
    for i, step in enumerate(path):
        if step.startswith("@"):
            if i != len(path) - 1:
                return None
            return parts.get(f"{path[i - 1]}{step}" if i else step) or ANYWHERE.get(step[1:])
        part = parts.get(step)
        if part is None or i == len(path) - 1:
            return part
        if path[i + 1].startswith("@"):
            continue                          # the attribute is listed in this context
        if part.within is None:
            return part
        parts = CONTENTS[part.within]
    return None


def _number(text: str) -> int | str | None:
    """A CycleTime as a number (its text if it is none: still compared), ``None`` if absent."""
    text = text.strip()
    if not text:
        return None
    try:
        return parse_int(text)
    except ValueError:
        return text


def _commands(el: Element) -> int:
    """Enabled InitCmds in ``el``'s ``InitCmds`` (or ``el`` itself being InitCmds)."""
    cmds = el if el.tag == "InitCmds" else el.find("InitCmds")
    if cmds is None:
        return 0
    return sum(1 for c in cmds.iterchildren("InitCmd")
               if _zero_or_absent(c.findtext("Disabled")))


def audit(config: Element, ignored: list[Unsupported] | None = None) -> list[Unsupported]:
    """Every refused or unknown part below ``config`` (the ``<Config>`` element); unknown
    metadata (``esi/vocabulary.py``: names, comments, tool data) goes to ``ignored``."""
    found: list[Unsupported] = []
    _walk(config, ROOT_CONTEXT, "", None, found, [] if ignored is None else ignored)
    cycle_times = {_number(c.findtext("CycleTime", "")) for c in config.iterchildren("Cyclic")}
    cycle_times.discard(None)
    if len(cycle_times) > 1:
        first = next(config.iterchildren("Cyclic"))
        listed = ", ".join(str(t) for t in sorted(
            cycle_times, key=lambda t: (isinstance(t, str), t if isinstance(t, int) else 0,
                                        str(t))))
        found.append(Unsupported(
            "Cyclic", f"cyclic tasks with different cycle times ({listed} µs): apply runs "
            "every frame in one cycle", first.sourceline))
    found += [part for _, part in _unmapped_fmmus(config)]
    found += [part for _, part in _refused_mailbox_cmds(config)]
    return found


def dropped_init_cmds(config: Element) -> set[Element]:
    """The refused parts that are InitCmds among commands the plan reads: the reader
    leaves them out of the plan, so that a skipping apply does not write them."""
    return {init for init, _ in _unmapped_fmmus(config) + _refused_mailbox_cmds(config)}


def _refused_mailbox_cmds(config: Element) -> list[tuple[Element, Unsupported]]:
    """Mailbox InitCmds refused one by one: those of a transition without a mailbox, then
    SoE ones that are no write request and FoE ones that are no read request (each command
    named once, for its first reason)."""
    found = _mailbox_without_mailbox(config)
    named = {init for init, _ in found}
    return found + [(init, part) for init, part in
                    _soe_not_write(config) + _foe_not_read_requests(config)
                    if init not in named]


def _mailbox_without_mailbox(config: Element) -> list[tuple[Element, Unsupported]]:
    """Enabled CoE, EoE, SoE and FoE InitCmds of a transition in which the slave has no
    mailbox to answer them (``esc.TRANSITION_RULES``: INIT->INIT, INIT->BOOT, BOOT->INIT): no
    master can run them there, and leaving them out unsaid would lose them."""
    found: list[tuple[Element, Unsupported]] = []
    for slave in config.iterchildren("Slave"):
        name = slave.findtext("Info/Name", "").strip() or f"line {slave.sourceline}"
        for protocol in ("CoE", "EoE", "SoE", "FoE"):
            for init in slave.iterfind(f"Mailbox/{protocol}/InitCmds/InitCmd"):
                if not _zero_or_absent(init.findtext("Disabled")):
                    continue
                for el in init.iterchildren("Transition"):
                    try:
                        transition = Transition(_text(el))
                    except ValueError:
                        continue              # the reader reports it with its line
                    rule = TRANSITION_RULES[transition]
                    if rule.mailbox:
                        continue
                    found.append((init, Unsupported(
                        f"{protocol}/InitCmds/InitCmd",
                        f"a {protocol} InitCmd in transition {transition.value} "
                        f"({transition.source.name}->{transition.target.name}): {rule.why}",
                        el.sourceline, name, 1)))
                    break
    return found


def _soe_not_write(config: Element) -> list[tuple[Element, Unsupported]]:
    """Enabled SoE InitCmds that are not write requests (OpCode 3, ETG.1000.6 §5.8): the
    schema documents the InitCmd as a "service channel write req", and a read (1) or a
    procedure command's other services would ask apply for what it does not do."""
    found: list[tuple[Element, Unsupported]] = []
    for slave in config.iterchildren("Slave"):
        name = slave.findtext("Info/Name", "").strip() or f"line {slave.sourceline}"
        for init in slave.iterfind("Mailbox/SoE/InitCmds/InitCmd"):
            op = init.find("OpCode")
            if op is None or not _zero_or_absent(init.findtext("Disabled")):
                continue                      # a missing OpCode: the reader's error
            code = _number(_text(op))
            if code == WRITE_REQUEST or not isinstance(code, int):
                continue                      # not a number: the reader's error, with its line
            found.append((init, Unsupported(
                "SoE/InitCmds/InitCmd", f"an SoE request with OpCode {code} (apply sends "
                f"write requests, OpCode {WRITE_REQUEST}, only)", op.sourceline, name, 1)))
    return found


# Why an FoE InitCmd other than a read request cannot be run (ETG.2100 MailboxCmdType: Data
# is "data of the mailbox cmd (excl. the mailbox)", one FoE message; esc.FoeOpCode).
_FOE_REFUSED: dict[int, str] = {
    FoeOpCode.WRITE: "a write request: Data holds the file name but an ENI has no place "
                     "for the file's contents, so apply cannot write the file",
    FoeOpCode.DATA: "a data packet: part of a transfer, not a request of its own",
    FoeOpCode.ACK: "an ack: part of a transfer, not a request of its own",
    FoeOpCode.ERROR: "an error: part of a transfer, not a request of its own",
    FoeOpCode.BUSY: "a busy reply: the slave's answer, not a request",
}


def _foe_not_read_requests(config: Element) -> list[tuple[Element, Unsupported]]:
    """Enabled FoE InitCmds whose Data is not an FoE read request (OpCode 1, password,
    file name): apply reads a file to its end and checks the slave serves it; anything
    else it cannot do faithfully (``_FOE_REFUSED``)."""
    found: list[tuple[Element, Unsupported]] = []
    for slave in config.iterchildren("Slave"):
        name = slave.findtext("Info/Name", "").strip() or f"line {slave.sourceline}"
        for init in slave.iterfind("Mailbox/FoE/InitCmds/InitCmd"):
            if not _zero_or_absent(init.findtext("Disabled")):
                continue
            try:
                data = bytes.fromhex(init.findtext("Data") or "")
            except ValueError:
                continue                      # the reader reports bad hex with its line
            if len(data) < FOE_HEADER.size:
                why = (f"<Data> of {len(data)} bytes: an FoE message has a "
                       f"{FOE_HEADER.size}-byte header (OpCode, reserved, UINT32)")
            elif data[0] == FoeOpCode.READ:
                continue
            else:
                why = _FOE_REFUSED.get(data[0], f"OpCode {data[0]}, none of 1-6")
            found.append((init, Unsupported("FoE/InitCmds/InitCmd", f"FoE InitCmd: {why}",
                                            init.sourceline, name, 1)))
    return found


# Logical commands (ETG.1000.4): the windows an FMMU's logical range must fall in.
_FMMU_FIRST, _FMMU_END, _FMMU_SIZE = 0x0600, 0x0700, 16
# The words of an FMMU setting outside every cyclic command, and of one EC-Engineer
# encrypted (``check`` tells the first, a fault of the file, from the second, which ecatcfg
# cannot read: eni/check/fmmus.py).
UNMAPPED_FMMU = "which no cyclic command covers"
ENCRYPTED_FMMU = "(encrypted: EncryptedEtherCATConfig, ecatcfg cannot decrypt it)"


def _unmapped_fmmus(config: Element) -> list[tuple[Element, Unsupported]]:
    """FMMU InitCmds whose logical range no cyclic command reads or writes: data that is
    not a clear FMMU setting.  EC-Engineer's ``EncryptedEtherCATConfig`` encrypts the
    process-data FMMU settings (the Murrelektronik VarioX export maps "logical
    0xEB030B5F"); written as they are, the slave's process data would be mapped nowhere."""
    windows: list[tuple[int, int]] = []
    for cmd in config.iterfind("Cyclic/Frame/Cmd"):
        kind, addr = _number(cmd.findtext("Cmd", "")), _number(cmd.findtext("Addr", ""))
        size = _hex_length(cmd.findtext("Data")) or _number(cmd.findtext("DataLength", ""))
        if kind in LOGICAL_CMDS and isinstance(addr, int) and isinstance(size, int):
            windows.append((addr, addr + size))
    root = config.getparent()
    encrypted = root is not None and root.tag == "EncryptedEtherCATConfig"
    found: list[tuple[Element, Unsupported]] = []
    for slave in config.iterchildren("Slave"):
        name = slave.findtext("Info/Name", "").strip() or None
        for init in slave.iterfind("InitCmds/InitCmd"):
            ado = _number(init.findtext("Ado", ""))
            if not isinstance(ado, int) or not _FMMU_FIRST <= ado < _FMMU_END:
                continue
            try:
                data = bytes.fromhex((init.findtext("Data") or "").strip())
            except ValueError:
                continue                      # the reader reports bad hex with its line
            for offset in range(0, len(data) - _FMMU_SIZE + 1, _FMMU_SIZE):
                record = data[offset:offset + _FMMU_SIZE]
                start, length = int.from_bytes(record[:4], "little"), record[4] | record[5] << 8
                if not record[12] & 1 or not record[11] & 3 or not length:
                    continue                  # inactive or unused: maps nothing
                if any(lo <= start and start + length <= hi for lo, hi in windows):
                    continue
                what = (f"FMMU {(ado - _FMMU_FIRST + offset) // _FMMU_SIZE} setting that maps "
                        f"logical 0x{start:08X}+{length}, which no cyclic command covers")
                what += (" (encrypted: EncryptedEtherCATConfig, ecatcfg cannot decrypt it)"
                         if encrypted else "")
                found.append((init, Unsupported("Slave/InitCmds/InitCmd", what,
                                                init.sourceline, name, 1)))
    return found


def _hex_length(text: str | None) -> int | None:
    text = (text or "").strip()
    return len(text) // 2 if text else None


def _walk(el: Element, context: str, path: str, slave: str | None,
          found: list[Unsupported], ignored: list[Unsupported]) -> None:
    parts = CONTENTS[context]
    for child in el:
        tag = child.tag
        if not isinstance(tag, str):          # comments, processing instructions
            continue
        where = f"{path}/{tag}" if path else tag
        part = parts.get(tag)
        if part is None:
            count = _commands(child) if context == "Slave/Mailbox" else 0
            if vocabulary.is_metadata(tag) and not _commands(child):   # no command lost
                ignored.append(Unsupported(where, f"<{tag}>, which ecatcfg does not read "
                                           f"here: {vocabulary.WORDS[tag][1]}",
                                           child.sourceline, slave))
            elif count:
                found.append(Unsupported(where, f"{tag} InitCmds (a mailbox protocol "
                                         "ecatcfg does not know)", child.sourceline, slave,
                                         count))
            else:
                found.append(Unsupported(where, f"<{tag}>, an element ecatcfg does not know",
                                         child.sourceline, slave))
            continue
        if part.kind == "refused":
            count = _commands(child) if part.counts else 0
            if part.empty_ok and not count:
                continue                      # <FoE/>, or only disabled commands: no loss
            found.append(Unsupported(where, part.text, child.sourceline, slave, count))
            continue
        name = slave
        if tag == "Slave":
            name = child.findtext("Info/Name", "").strip() or f"line {child.sourceline}"
        if part.check is not None:
            problem = part.check(child)
            if problem:
                found.append(Unsupported(where, problem, child.sourceline, slave))
                continue
        if _attributes(child, parts, where, name, found, ignored) and part.within is not None:
            _walk(child, part.within, where, name, found, ignored)


def _attributes(el: Element, parts: dict[str, Part], where: str, slave: str | None,
                found: list[Unsupported], ignored: list[Unsupported]) -> bool:
    """Each attribute of ``el`` must be listed as ``Tag@Name`` in its context, like an
    element, or be one with a meaning of its own (:data:`ANYWHERE`): an attribute can change
    what the master does (``HotPlug``, ``CycleTimeFactor``) as much as an element can.  One
    that is neither is ignored with a warning when it is metadata (a name, a tool's data:
    ``esi/vocabulary.py``), refused otherwise.  ``False`` when one is refused; the element
    itself stays in the plan (a skipping apply still sends an InitCmd whose attribute it
    refused: it skips what it does not know, never the command)."""
    ok = True
    for name, value in el.attrib.items():
        if name.startswith("{"):
            continue                          # xsi:... and other namespaces: schema hints
        part = parts.get(f"{el.tag!s}@{name}") or ANYWHERE.get(name)
        at = f"{where}/@{name}"
        if part is None and vocabulary.is_metadata(name, attribute=True):
            ignored.append(Unsupported(at, f"the attribute {name}={value!r} of <{el.tag!s}>, "
                                       "which ecatcfg does not read here: "
                                       f"{vocabulary.WORDS['@' + name][1]}",
                                       el.sourceline, slave))
            continue
        if part is None:
            found.append(Unsupported(at, f"the attribute {name}={value!r} of <{el.tag!s}>, "
                                     "which ecatcfg does not know", el.sourceline, slave))
        elif part.kind == "refused":
            found.append(Unsupported(at, part.text, el.sourceline, slave))
        elif part.check is not None and (problem := part.check(el)):
            found.append(Unsupported(at, problem, el.sourceline, slave))
        else:
            continue
        ok = False
    return ok


def table() -> list[tuple[str, str, str]]:
    """``(elements, kind, text)`` for every listed element and attribute, in the order
    above, those of one context with the same kind and text on one row: the table
    ``docs/runtime.md`` shows."""
    rows: dict[tuple[str, str, str], list[str]] = {}
    for tag, part in ROOT.items():
        rows.setdefault(("EtherCATConfig", part.kind, part.text), []).append(tag)
    for context, parts in CONTENTS.items():
        for tag, part in parts.items():
            rows.setdefault((context, part.kind, part.text), []).append(tag)
    for name, part in ANYWHERE.items():
        rows.setdefault(("*", part.kind, part.text), []).append(f"@{name}")
    return [(f"{context}{'' if tags[0][0] == '@' else '/'}{tags[0]}" if len(tags) == 1
             else f"{context}/{{{', '.join(tags)}}}",
             kind, text) for (context, kind, text), tags in rows.items()]


# -- refusing, or skipping with a warning ---------------------------------------------------

SKIP_HINT = "--skip-unsupported applies it without them"


class UnsupportedEniError(EcatcfgError):
    """An ENI that asks for what apply does not do; raised before anything is sent."""

    def __init__(self, message: str, file: str | None, parts: list[Unsupported]) -> None:
        super().__init__(message, file)
        self.parts = parts


def _owner(part: Unsupported) -> str:
    return f"slave {part.slave!r}" if part.slave is not None else "the master"


def line_of(part: Unsupported, file: str | None) -> str:
    """``eni.xml:210: slave 'Drive': VoE InitCmds (vendor-specific mailbox messages): 3
    commands would be lost``."""
    where = location(file, part.line)
    lost = (f": {part.commands} command{'s' if part.commands != 1 else ''} would be lost"
            if part.commands else "")
    return f"{where + ': ' if where else ''}{_owner(part)}: {part.what} [{part.element}]{lost}"


def refuse(plan: NetworkPlan, file: str | None) -> None:
    """Raise :class:`UnsupportedEniError` listing every unsupported part of ``plan``."""
    if not plan.unsupported:
        return
    n = len(plan.unsupported)
    lines = "\n".join("  " + line_of(p, file) for p in plan.unsupported)
    raise UnsupportedEniError(
        f"the ENI asks for {n} thing{'s' if n != 1 else ''} apply does not do; nothing was "
        f"written to the bus:\n{lines}\n{SKIP_HINT}", file, plan.unsupported)


def ignored_warnings(plan: NetworkPlan, file: str | None) -> list[str]:
    """One warning per piece of unknown metadata the reader left out
    (``NetworkPlan.ignored``): ``eni.xml:12: slave 'Drive': ignored <DisplayName>, which
    ecatcfg does not read here: a name ... [Slave/Info/DisplayName]``."""
    out = []
    for p in plan.ignored:
        where = location(file, p.line)
        out.append(f"{where + ': ' if where else ''}{_owner(p)}: ignored {p.what} "
                   f"[{p.element}]")
    return out


def skip_warnings(plan: NetworkPlan, file: str | None) -> list[str]:
    """One warning per slave (and one for the master) naming what is skipped:
    ``eni.xml: slave 'Drive': skipped VoE InitCmds (vendor-specific mailbox messages)
    [Slave/Mailbox/VoE] at line 210, 3 commands not sent``."""
    owners: dict[str, list[Unsupported]] = {}
    for part in plan.unsupported:
        owners.setdefault(_owner(part), []).append(part)

    def one(p: Unsupported) -> str:
        sent = f", {p.commands} command{'s' if p.commands != 1 else ''} not sent" \
            if p.commands else ""
        return f"{p.what} [{p.element}]" + (f" at line {p.line}" if p.line else "") + sent

    prefix = f"{file}: " if file else ""
    return [f"{prefix}{owner}: skipped " + "; ".join(one(p) for p in parts)
            for owner, parts in owners.items()]
