"""Faults planted into real ENI files, by a seeded generator: the cases of the check-vs-apply
agreement (tests/test_agreement.py, bench/agreement.py).

Each fault class is a function that changes one ENI's XML tree (lxml) the way a person or a
tool gets it wrong, and returns where: the slave and the element whose line ``check`` must
name (an lxml path, found again in the written file), or ``None`` when the file has no place
for that fault (no CoE PDO assignment to shorten, one slave only for an overlap, ...).  The
choice of slave and object is the generator's ``random.Random(seed)``, so a failing case is
repeated by its (file, fault, seed).

Each class also says what a slave does with it (``slave_refuses``): ``True`` when a slave
refuses a state (an AL status code or an SDO abort), ``False`` when every slave takes it and
the fault is in the master's process image only (data in the wrong bits: no emulator and no
real slave can tell, only ``check`` can, from the whole file), ``"esi"`` when only a slave
that knows its ESI refuses it (a device emulated from the ENI alone takes the ENI's word),
``"firmware"`` when only a slave with firmware checks it (one without a mailbox runs in ESC
device emulation: no firmware looks at its SyncManagers).
The references for each are in its docstring.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal

from lxml import etree

Root = etree._Element
Refusal = Literal[True, False, "esi", "firmware"]

SM_ASSIGN = range(0x1C10, 0x1C30)
RX_MAPPING = range(0x1600, 0x1800)
TX_MAPPING = range(0x1A00, 0x1C00)
FMMU_ADO = range(0x0600, 0x0700)
SM_ADO = range(0x0800, 0x0900)
LOGICAL = {10, 11, 12}                       # LRD, LWR, LRW (ETG.1000.4)


@dataclass(frozen=True)
class Planted:
    slave: str | None          # the slave's Info/Name (None: a cyclic command)
    path: str                  # tree.getpath() of the element check must name ...
    what: str                  # in words, for messages
    firmware: bool = True      # the slave has a mailbox (else: ESC device emulation)
    also: tuple[str, ...] = ()  # ... or of one of these (one fault, several elements)
    identity: tuple[int, int, int] | None = None     # the slave's vendor, product, revision


@dataclass(frozen=True)
class Fault:
    name: str
    plant: Callable[[Root, random.Random], Planted | None]
    slave_refuses: Refusal


def number(text: str | None) -> int:
    """An ENI number: decimal, ``#x..`` or ``0x..`` (ETG.2100 HexDecValue)."""
    t = (text or "0").strip()
    if t[:2].lower() in ("#x", "0x"):
        return int(t[2:], 16)
    return int(t)


def _name(slave: Root) -> str:
    return (slave.findtext("Info/Name") or "").strip()


def _path(el: Root) -> str:
    return str(el.getroottree().getpath(el))


def _slaves(root: Root) -> list[Root]:
    return list(root.iterfind("Config/Slave"))


def _enabled(cmd: Root) -> bool:
    return cmd.findtext("Disabled", "").strip().lower() not in ("1", "true")


def _coe(slave: Root) -> list[Root]:
    return [c for c in slave.iterfind("Mailbox/CoE/InitCmds/InitCmd")
            if number(c.findtext("Ccs", "1")) == 1 and _enabled(c)
            and c.find("Data") is not None]


def _complete(cmd: Root) -> bool:
    return cmd.get("CompleteAccess", "").strip().lower() in ("1", "true")


def _data(cmd: Root) -> bytes:
    return bytes.fromhex((cmd.findtext("Data") or "").strip())


def _set_data(cmd: Root, data: bytes) -> None:
    el = cmd.find("Data")
    assert el is not None
    el.text = data.hex()


def _registers(slave: Root, area: range, size: int) -> list[tuple[Root, int]]:
    """(InitCmd, record number) of register writes of whole records in ``area``."""
    out = []
    for cmd in slave.iterfind("InitCmds/InitCmd"):
        ado = number(cmd.findtext("Ado"))
        data = (cmd.findtext("Data") or "").strip()
        if ado in area and (ado - area.start) % size == 0 and len(data) == 2 * size \
                and number(cmd.findtext("Cmd")) in (2, 5, 8, 11, 14):
            out.append((cmd, (ado - area.start) // size))
    return out


def _fmmus(slave: Root, kinds: tuple[int, ...] = (1, 2, 3)) -> list[Root]:
    """InitCmds that set an active FMMU of one of ``kinds`` (1 read, 2 write)."""
    out = []
    for cmd, _ in _registers(slave, FMMU_ADO, 16):
        d = _data(cmd)
        physical = int.from_bytes(d[8:10], "little")
        # process data only: not an FMMU over a register (SM1's status byte, 0x080D)
        if d[12] & 1 and d[11] & 3 in kinds and int.from_bytes(d[4:6], "little") \
                and physical >= 0x1000:
            out.append(cmd)
    return out


def _pick(rng: random.Random, items: list[Root]) -> Root | None:
    return rng.choice(items) if items else None


# -- PDO assignment and mapping over CoE -------------------------------------------------

def _last_assigned(slave: Root, count_cmd: Root) -> int | None:
    """The PDO a count download's last entry names (the one a count one short drops)."""
    index, data = number(count_cmd.findtext("Index")), _data(count_cmd)
    if _complete(count_cmd):
        k = 2 + 2 * (data[0] - 1)
        return int.from_bytes(data[k:k + 2], "little") if k + 2 <= len(data) else None
    for cmd in _coe(slave):
        if number(cmd.findtext("Index")) == index \
                and number(cmd.findtext("SubIndex")) == data[0] and len(_data(cmd)) == 2:
            return int.from_bytes(_data(cmd), "little")
    return None


def _carries(slave: Root, pdo: int | None) -> bool:
    """Whether PDO ``pdo`` moves data, as far as the ENI says (a PDO it does not describe
    is taken to): dropping an empty one changes nothing a slave or check could see."""
    if pdo is None:
        return True
    for desc in slave.iterfind("ProcessData/*"):
        if desc.tag in ("RxPdo", "TxPdo") and number(desc.findtext("Index")) == pdo:
            return any(number(e.findtext("BitLen")) for e in desc.iterfind("Entry"))
    return True


def assign_short(root: Root, rng: random.Random) -> Planted | None:
    """The PDO assignment's count one short (4 PDOs where SM2's length needs 5): the slave
    checks the SM length against the PDOs assigned and refuses SAFEOP with 0x001D/0x001E
    (SOES ESC_checkSM23; ETG.1000.6 PDO assignment)."""
    found = []
    for slave in _slaves(root):
        for cmd in _coe(slave):
            index, data = number(cmd.findtext("Index")), _data(cmd)
            if index in SM_ASSIGN and number(cmd.findtext("SubIndex")) == 0 and data \
                    and data[0] >= 2 and _carries(slave, _last_assigned(slave, cmd)):
                found.append((slave, cmd))
    if not found:
        return None
    slave, cmd = rng.choice(found)
    data = bytearray(_data(cmd))
    data[0] -= 1
    _set_data(cmd, bytes(data))
    return Planted(_name(slave), _path(cmd), f"0x{number(cmd.findtext('Index')):04X} count "
                   f"{data[0]}")


def assign_missing(root: Root, rng: random.Random) -> Planted | None:
    """An assigned PDO that does not exist (0x16FF / 0x1AFF): the slave has no such mapping
    object and refuses the assignment or SAFEOP (ETG.1000.6: abort 0x06090030 or 0x001D)."""
    found = []
    for slave in _slaves(root):
        for cmd in _coe(slave):
            index, data = number(cmd.findtext("Index")), _data(cmd)
            if index in SM_ASSIGN and number(cmd.findtext("SubIndex")) >= 1 \
                    and not _complete(cmd) and len(data) == 2:
                found.append((slave, cmd))
    if not found:
        return None
    slave, cmd = rng.choice(found)
    pdo = int.from_bytes(_data(cmd), "little")
    bogus = 0x16FF if pdo in RX_MAPPING else 0x1AFF
    _set_data(cmd, bogus.to_bytes(2, "little"))
    return Planted(_name(slave), _path(cmd), f"assigns 0x{bogus:04X}")


def _assigned(slave: Root) -> set[int]:
    """The PDOs ProcessData/Sm lists or the CoE assignment downloads name."""
    found = {number(p.text) for p in slave.iterfind("ProcessData/*/Pdo")}
    for cmd in _coe(slave):
        if number(cmd.findtext("Index")) in SM_ASSIGN:
            data = _data(cmd)
            start = 2 if _complete(cmd) and number(cmd.findtext("SubIndex")) == 0 else 0
            if _complete(cmd) or number(cmd.findtext("SubIndex")) >= 1:
                found |= {int.from_bytes(data[k:k + 2], "little")
                          for k in range(start, len(data) - 1, 2)}
    return found


def _mapping_writes(root: Root) -> list[tuple[Root, Root, int]]:
    """(slave, download, byte offset) of each entry of an assigned PDO's mapping object a
    download writes: one entry's own download (offset 0), or an entry inside a
    CompleteAccess download from subindex 0 (2 bytes of count, then 4 per entry)."""
    found = []
    for slave in _slaves(root):
        assigned = _assigned(slave)
        for cmd in _coe(slave):
            index, data = number(cmd.findtext("Index")), _data(cmd)
            if not (index in RX_MAPPING or index in TX_MAPPING) or index not in assigned:
                continue
            sub = number(cmd.findtext("SubIndex"))
            if not _complete(cmd) and sub >= 1 and len(data) == 4:
                offsets = [0]
            elif _complete(cmd) and sub == 0 and data:
                offsets = [2 + 4 * k for k in range(data[0]) if 2 + 4 * k + 4 <= len(data)]
            else:
                continue
            for off in offsets:
                entry = data[off:off + 4]
                if entry[3] | entry[2] and entry[0] in (8, 16, 32):
                    found.append((slave, cmd, off))
    return found


def _change_entry(cmd: Root, offset: int, entry: bytes) -> None:
    data = bytearray(_data(cmd))
    data[offset:offset + 4] = entry
    _set_data(cmd, bytes(data))


def mapping_size(root: Root, rng: random.Random) -> Planted | None:
    """A CoE mapping download with another bit length than the ENI's ProcessData says: the
    PDO's size changes, the SM length no longer fits and the slave refuses SAFEOP (0x001D /
    0x001E; SOES sizes PDOs from the mapping objects)."""
    found = _mapping_writes(root)
    if not found:
        return None
    slave, cmd, off = rng.choice(found)
    entry = bytearray(_data(cmd)[off:off + 4])
    entry[0] = 16 if entry[0] == 32 else entry[0] * 2
    _change_entry(cmd, off, bytes(entry))
    return Planted(_name(slave), _path(cmd), f"maps {entry[0]} bits")


def mapping_names_other(root: Root, rng: random.Random) -> Planted | None:
    """A CoE mapping download of another subindex of the same object, of the same size, than
    ProcessData names: the slave takes it (the sizes fit), the master reads one variable
    where the slave puts another."""
    found = _mapping_writes(root)
    if not found:
        return None
    slave, cmd, off = rng.choice(found)
    entry = bytearray(_data(cmd)[off:off + 4])
    entry[1] ^= 0x01
    _change_entry(cmd, off, bytes(entry))
    return Planted(_name(slave), _path(cmd), f"maps subindex {entry[1]}")


def not_mappable(root: Root, rng: random.Random) -> Planted | None:
    """A CoE mapping download that maps 0x1018:01 (identity: vendor id), which no
    dictionary lets a PDO map (ETG.1000.6 0x1018 is a constant); the slave aborts the
    download (0x06040041) or refuses SAFEOP.  From the ENI alone the object is whatever
    the ENI says: only a device known from its ESI refuses it."""
    found = [(s, c, o) for s, c, o in _mapping_writes(root) if _data(c)[o] == 32]
    if not found:
        return None
    slave, cmd, off = rng.choice(found)
    _change_entry(cmd, off, bytes([32, 1, 0x18, 0x10]))
    return Planted(_name(slave), _path(cmd), "maps 0x1018:01")


# -- SyncManagers and FMMUs ----------------------------------------------------------------

def sm_direction(root: Root, rng: random.Random) -> Planted | None:
    """An output SM whose control byte says "read" (direction bits 2-3 = 00): the slave
    compares mode and direction with its own SM configuration and refuses SAFEOP (0x001D;
    SOES ESC_checkSM23)."""
    found = []
    for slave in _slaves(root):
        for cmd, n in _registers(slave, SM_ADO, 8):
            d = _data(cmd)
            if n >= 2 and d[6] & 1 and d[4] & 0x0C == 0x04 and int.from_bytes(d[2:4], "little"):
                found.append((slave, cmd))
    if not found:
        return None
    slave, cmd = rng.choice(found)
    d = bytearray(_data(cmd))
    d[4] &= ~0x0C & 0xFF
    _set_data(cmd, bytes(d))
    return Planted(_name(slave), _path(cmd), "output SM set to read")


def _set_fmmu(cmd: Root, **fields: int) -> None:
    d = bytearray(_data(cmd))
    for name, value in fields.items():
        if name == "logical":
            d[0:4] = value.to_bytes(4, "little")
        elif name == "start_bit":
            d[6] = value
        elif name == "stop_bit":
            d[7] = value
    _set_data(cmd, bytes(d))


def fmmu_overlap(root: Root, rng: random.Random) -> Planted | None:
    """One slave's read FMMU moved onto another slave's inputs: both slaves write the same
    bits of the frame.  Each slave takes its FMMU (an ESC does not know the others)."""
    reads = [(s, c) for s in _slaves(root) for c in _fmmus(s, (1,))]
    pairs = [(a, b) for a in reads for b in reads if a[0] is not b[0]]
    if not pairs:
        return None
    (other, target), (slave, cmd) = rng.choice(pairs)
    t = _data(target)
    _set_fmmu(cmd, logical=int.from_bytes(t[0:4], "little"), start_bit=t[6])
    return Planted(_name(slave), _path(cmd), f"onto slave {_name(other)!r}'s inputs")


def fmmu_end_short(root: Root, rng: random.Random) -> Planted | None:
    """A read FMMU whose stop bit leaves 4 of the slave's inputs unmapped (stop bit 3 where
    the bits reach bit 7): the ESC takes it; 4 inputs never reach the master."""
    found = [(s, c) for s in _slaves(root) for c in _fmmus(s, (1,)) if _data(c)[7] == 7
             and _data(c)[6] == 0]
    if not found:
        return None
    slave, cmd = rng.choice(found)
    _set_fmmu(cmd, stop_bit=3)
    return Planted(_name(slave), _path(cmd), "stop bit 3")


def fmmu_start_bit(root: Root, rng: random.Random) -> Planted | None:
    """An FMMU with logical start bit 4 over a slave whose bits start at bit 0: the ESC
    maps 4 bits fewer from another place; the slave takes it."""
    found = [(s, c) for s in _slaves(root) for c in _fmmus(s) if _data(c)[6] == 0
             and (int.from_bytes(_data(c)[4:6], "little") > 1 or _data(c)[7] >= 4)]
    if not found:
        return None
    slave, cmd = rng.choice(found)
    _set_fmmu(cmd, start_bit=4)
    return Planted(_name(slave), _path(cmd), "start bit 4")


def _cyclic_logical(root: Root) -> list[tuple[int, int, Root]]:
    out = []
    for cmd in root.iterfind("Config/Cyclic/Frame/Cmd"):
        if number(cmd.findtext("Cmd")) in LOGICAL and cmd.find("Addr") is not None:
            out.append((number(cmd.findtext("Addr")), number(cmd.findtext("DataLength")), cmd))
    return out


def fmmu_past_command(root: Root, rng: random.Random) -> Planted | None:
    """An FMMU that starts inside a logical cyclic command and ends past it: its last
    bytes are in no datagram (a slave's outputs there are never written, inputs never
    read)."""
    cmds = _cyclic_logical(root)
    found = []
    for s in _slaves(root):
        for c in _fmmus(s):
            d = _data(c)
            start, length = int.from_bytes(d[0:4], "little"), int.from_bytes(d[4:6], "little")
            for addr, n, _ in cmds:
                if addr <= start < addr + n and length >= 1:
                    found.append((s, c, addr + n - 1))
    if not found:
        return None
    slave, cmd, last = rng.choice(found)
    d = _data(cmd)
    if int.from_bytes(d[4:6], "little") == 1:
        # a one-byte FMMU cannot start inside and end past: two bytes from the last one
        dd = bytearray(d)
        dd[4:6] = (2).to_bytes(2, "little")
        _set_data(cmd, bytes(dd))
    _set_fmmu(cmd, logical=last)
    return Planted(_name(slave), _path(cmd), f"from 0x{last:08X}, past the command")


def fmmu_outside(root: Root, rng: random.Random) -> Planted | None:
    """An FMMU moved past every cyclic command: the slave's process data is exchanged by
    no datagram, and the working counter is one short."""
    cmds = _cyclic_logical(root)
    found = [(s, c) for s in _slaves(root) for c in _fmmus(s)]
    if not found or not cmds:
        return None
    slave, cmd = rng.choice(found)
    end = max(a + n for a, n, _ in cmds)
    _set_fmmu(cmd, logical=end + 0x100)
    return Planted(_name(slave), _path(cmd), f"at 0x{end + 0x100:08X}")


def wrong_cnt(root: Root, rng: random.Random) -> Planted | None:
    """A logical cyclic command's Cnt one more than the FMMUs give: every cycle is taken as
    failed (ETG.1000.4 working counter)."""
    cmds = [c for _, _, c in _cyclic_logical(root) if c.find("Cnt") is not None]
    cmd = _pick(rng, cmds)
    if cmd is None:
        return None
    cnt = cmd.find("Cnt")
    assert cnt is not None
    cnt.text = str(number(cnt.text) + 1)
    return Planted(None, _path(cmd), f"Cnt {cnt.text}")


# -- DC and mailbox --------------------------------------------------------------------------

def sync0_fast(root: Root, rng: random.Random) -> Planted | None:
    """A SYNC0 cycle of 20 µs (register 0x09A0 and DC/CycleTime0): below the minimum cycle
    time of every device of the corpus with one (0x1C32:05); Slave Stack Code refuses
    SAFEOP with 0x0035 (ETG.1020).  A device without a minimum takes it."""
    found = []
    for slave in _slaves(root):
        writes = [c for c in slave.iterfind("InitCmds/InitCmd")
                  if number(c.findtext("Ado")) == 0x09A0 and c.findtext("Data")]
        active = [c for c in slave.iterfind("InitCmds/InitCmd")
                  if number(c.findtext("Ado")) == 0x0980 and len(_data(c)) == 2
                  and _data(c)[1] & 0x03 == 0x03]
        if writes and active and slave.find("DC/CycleTime0") is not None:
            found.append((slave, writes))
    if not found:
        return None
    slave, writes = rng.choice(found)
    for c in writes:
        d = bytearray(_data(c))
        d[0:4] = (20_000).to_bytes(4, "little")
        _set_data(c, bytes(d))
    cycle = slave.find("DC/CycleTime0")
    assert cycle is not None
    cycle.text = "20000"
    return Planted(_name(slave), _path(cycle), "SYNC0 20 µs",
                   also=(_path(slave.find("DC")), *map(_path, writes)))


def sync0_zero(root: Root, rng: random.Random) -> Planted | None:
    """SYNC0 switched on with the SYNC0 cycle register (0x09A0) written 0, the DC element
    left as it was (a tool that writes the register from another field): SYNC0 is then a
    single pulse (ESC Section II), and a slave with firmware refuses SAFEOP with 0x0035
    (the Slave Stack Code's StartInputHandler).  A device without firmware takes it."""
    found = []
    for slave in _slaves(root):
        writes = [c for c in slave.iterfind("InitCmds/InitCmd")
                  if number(c.findtext("Ado")) == 0x09A0 and len(_data(c)) >= 4]
        active = [c for c in slave.iterfind("InitCmds/InitCmd")
                  if number(c.findtext("Ado")) == 0x0980 and len(_data(c)) == 2
                  and _data(c)[1] & 0x03 == 0x03]
        if writes and active:
            found.append((slave, writes))
    if not found:
        return None
    slave, writes = rng.choice(found)
    for c in writes:
        d = bytearray(_data(c))
        d[0:4] = bytes(4)
        _set_data(c, bytes(d))
    return Planted(_name(slave), _path(writes[-1]), "SYNC0 cycle register 0",
                   also=tuple(map(_path, writes[:-1])))


def maps_device_type(root: Root, rng: random.Random) -> Planted | None:
    """A 32-bit entry of a PDO replaced by 0x1000:00 (device type) in the mapping download
    and in ``ProcessData`` alike (a tool that maps the object and describes it so): the ENI
    agrees with itself, but ETG.1000.6 gives 0x1000 no PDO mapping.  A slave whose
    dictionary says so (its ESI's Flags without PdoMapping) refuses the mapping or SAFEOP;
    from the ENI alone the object is what the ENI says, and a dictionary that gives no
    Flags for it leaves it to the device (docs/show-diff-check.md)."""
    found = []
    for slave, cmd, off in _mapping_writes(root):
        entry = _data(cmd)[off:off + 4]
        index, sub = int.from_bytes(entry[2:4], "little"), entry[1]
        pdo = number(cmd.findtext("Index"))
        descs = [e for d in slave.iterfind("ProcessData/*") if d.tag in ("RxPdo", "TxPdo")
                 and number(d.findtext("Index")) == pdo for e in d.iterfind("Entry")
                 if number(e.findtext("Index")) == index
                 and number(e.findtext("SubIndex")) == sub and number(e.findtext("BitLen")) == 32]
        if entry[0] == 32 and descs:
            found.append((slave, cmd, off, descs[0]))
    if not found:
        return None
    slave, cmd, off, desc = rng.choice(found)
    _change_entry(cmd, off, bytes([32, 0, 0x00, 0x10]))
    for tag, text in (("Index", "#x1000"), ("SubIndex", "0")):
        el = desc.find(tag)
        if el is not None:
            el.text = text
    return Planted(_name(slave), _path(cmd), "maps 0x1000:00", also=(_path(desc),))


def mailbox_size(root: Root, rng: random.Random) -> Planted | None:
    """SM0 and Mailbox/Send of one slave both 1000 bytes: the ENI agrees with itself, but
    the device's mailbox is another size and it refuses PREOP (0x0016, SOES
    ESC_checkmbx)."""
    found = []
    for slave in _slaves(root):
        sm0 = [c for c, n in _registers(slave, SM_ADO, 8) if n == 0 and _data(c)[6] & 1]
        if sm0 and slave.find("Mailbox/Send/Length") is not None:
            found.append((slave, sm0))
    if not found:
        return None
    slave, sm0 = rng.choice(found)
    for c in sm0:
        d = bytearray(_data(c))
        d[2:4] = (1000).to_bytes(2, "little")
        _set_data(c, bytes(d))
    length = slave.find("Mailbox/Send/Length")
    assert length is not None
    length.text = "1000"
    return Planted(_name(slave), _path(slave.find("Mailbox/Send")), "mailbox 1000 bytes",
                   also=tuple(_path(c) for c in sm0))


def watchdog(root: Root, rng: random.Random) -> Planted | None:
    """The SM watchdog time (0x0420) set to 1 unit (100 µs with the default divider) on a
    slave whose output SM has its watchdog on: it expires between two frames of any
    cycle of the corpus, and a slave with firmware leaves OP with 0x001B (ESC Section II;
    a device without firmware only clears its output pins)."""
    found = []
    for slave in _slaves(root):
        watched = any(n >= 2 and _data(c)[4] & 0x4C == 0x44 and _data(c)[6] & 1
                      for c, n in _registers(slave, SM_ADO, 8))
        writes = [c for c in slave.iterfind("InitCmds/InitCmd")
                  if number(c.findtext("Ado")) == 0x0420 and len(_data(c)) == 2]
        if watched and writes:
            found.append((slave, writes[-1]))
    if not found:
        return None
    slave, cmd = rng.choice(found)
    _set_data(cmd, (1).to_bytes(2, "little"))
    return Planted(_name(slave), _path(cmd), "SM watchdog 1 unit")


FAULTS: dict[str, Fault] = {f.name: f for f in (
    Fault("assign-short", assign_short, True),
    Fault("assign-missing", assign_missing, True),
    Fault("mapping-size", mapping_size, True),
    Fault("mapping-names-other", mapping_names_other, False),
    Fault("not-mappable", not_mappable, "esi"),
    Fault("sm-direction", sm_direction, "firmware"),
    Fault("fmmu-overlap", fmmu_overlap, False),
    Fault("fmmu-end-short", fmmu_end_short, False),
    Fault("fmmu-start-bit", fmmu_start_bit, False),
    Fault("fmmu-past-command", fmmu_past_command, False),
    Fault("fmmu-outside", fmmu_outside, False),
    Fault("wrong-cnt", wrong_cnt, False),
    Fault("sync0-fast", sync0_fast, "esi"),
    Fault("sync0-zero", sync0_zero, "firmware"),
    Fault("maps-device-type", maps_device_type, "esi"),
    Fault("mailbox-size", mailbox_size, "esi"),
    Fault("watchdog", watchdog, "firmware"),
)}


def plant(data: bytes, fault: str, seed: int) -> tuple[bytes, Planted] | None:
    """The ENI ``data`` with ``fault`` planted by ``random.Random(seed)``, and where; None
    when the file has no place for it."""
    parser = etree.XMLParser(remove_blank_text=False, resolve_entities=False)
    tree = etree.ElementTree(etree.fromstring(data, parser))
    planted = FAULTS[fault].plant(tree.getroot(), random.Random(f"{fault}:{seed}"))
    if planted is None:
        return None
    owner = [s for s in _slaves(tree.getroot()) if _name(s) == planted.slave]
    if owner:
        identity = tuple(number(owner[0].findtext(f"Info/{t}"))
                         for t in ("VendorId", "ProductCode", "RevisionNo"))
        planted = replace(planted, firmware=owner[0].find("Mailbox") is not None,
                          identity=(identity[0], identity[1], identity[2]))
    return etree.tostring(tree, xml_declaration=True, encoding="UTF-8"), planted


def lines_of(data: bytes, planted: Planted) -> set[int]:
    """The lines of the planted fault's elements in the file ``data``."""
    tree = etree.ElementTree(etree.fromstring(data))
    return {int(tree.xpath(p)[0].sourceline) for p in (planted.path, *planted.also)}
