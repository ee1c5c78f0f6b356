"""CoE InitCmds for PDO assignment (0x1C1n) and mapping (0x16xx / 0x1Axx), PREOP→SAFEOP.

The sequence is ETG.1020's 6-step procedure, in the order TwinCAT and EC-Engineer write it
(``docs/eni-exports.md`` §5): stop every assignment (``0x1C12:00 = 0``), clear the
configurable PDOs that stay unassigned, write each remapped PDO (``:00 = 0``, entries,
count), then write each assignment (entries, then the count, which re-enables it).  With CoE
CompleteAccess in the ESI, a whole assignment or mapping is one download at subindex 0
(count, a padding byte, then the entries).

Clearing unassigned configurable PDOs: EC-Engineer does it (``clear pdo 0x1A07 entries`` for
the Elmo Gold) and so do we, so a mapping some earlier tool left in the slave cannot linger on
a PDO the ENI says is empty.  Only PDOs the dictionary (when there is one) shows writable in
PREOP are cleared: clearing a PDO the slave refuses would stop the bring-up.
"""

from __future__ import annotations

import struct

from ecatcfg.eni.plan import CoeInitCmd, PdoDesc, PdoEntryDesc
from ecatcfg.compiler.resolve import ResolvedSlave, kept_by_dictionary
from ecatcfg.esc import SM_PDO_ASSIGN, Transition
from ecatcfg.esi.coe import DictEntry, lookup, write_refusal



def _cmd(comment: str, index: int, subindex: int, data: bytes,
         complete_access: bool = False) -> CoeInitCmd:
    return CoeInitCmd([Transition.PS], comment, index, subindex, data,
                      complete_access=complete_access, fixed=True)


def _clearable(slave: ResolvedSlave, index: int) -> bool:
    """Whether PDO ``index`` may be cleared: its object is in the dictionary (when the
    slave has one) and writable in PREOP."""
    dic, local = slave.dictionary_for(index)
    if dic is None or not dic.objects:
        return True
    found = lookup(dic, local, 0)
    return isinstance(found, DictEntry) and write_refusal(found, "PreOp") is None


def _entry_word(e: PdoEntryDesc) -> bytes:
    return struct.pack("<I", (e.index << 16) | (e.subindex << 8) | e.bit_len)


def pdo_cmds(slave: ResolvedSlave) -> list[CoeInitCmd]:
    dev = slave.device
    coe = dev.mailbox.coe if dev.mailbox else None
    if coe is None or not (coe.pdo_assign or coe.pdo_config):
        return []
    ca = coe.complete_access
    sms = sorted({sm.number for sm in dev.sms
                  if not sm.is_mailbox and not sm.virtual and sm.type in ("Outputs", "Inputs")})
    # PdoConfig without PdoAssign (a fixed assignment of configurable PDOs): a remapped PDO
    # is still downloaded, or the slave would keep its old entries while the SMs are sized
    # for the new ones.
    # An assignment or mapping the dictionary does not let PREOP write stays as the slave
    # has it (resolve refuses a topology that changes it): writing it would stop PS.
    assigned = [n for n in sms if not kept_by_dictionary(slave, SM_PDO_ASSIGN + n)] \
        if coe.pdo_assign else []
    cmds = [_cmd(f"clear sm pdos (0x{SM_PDO_ASSIGN + n:04X})", SM_PDO_ASSIGN + n, 0, b"\x00")
            for n in assigned]
    if coe.pdo_config:
        # TxPDOs first, as EC-Engineer lists and clears them.
        for p in sorted(slave.pdos, key=lambda p: p.direction != "tx"):
            if coe.pdo_assign and not p.fixed and not p.virtual and p.sm is None \
                    and _clearable(slave, p.index):
                cmds.append(_cmd(f"clear pdo 0x{p.index:04X} entries", p.index, 0, b"\x00"))
        for p in slave.pdos:
            # Without PdoAssign only what the user remapped: the rest stays as the slave has it.
            if p.sm is not None and not p.fixed and (
                    p.index in slave.remapped or (coe.pdo_assign and p.entries)) \
                    and not kept_by_dictionary(slave, p.index):
                cmds += _mapping(p, ca)
    for n in assigned:
        cmds += _assignment(SM_PDO_ASSIGN + n, slave.assigned(n), ca)
    return cmds


def _mapping(p: PdoDesc, ca: bool) -> list[CoeInitCmd]:
    words = [_entry_word(e) for e in p.entries]
    if ca:
        return [_cmd(f"download pdo 0x{p.index:04X} entries", p.index, 0,
                     bytes([len(words), 0]) + b"".join(words), complete_access=True)]
    cmds = [_cmd(f"clear pdo 0x{p.index:04X} entries", p.index, 0, b"\x00")]
    cmds += [_cmd(f"download pdo 0x{p.index:04X} entry", p.index, i, w)
             for i, w in enumerate(words, start=1)]
    cmds.append(_cmd(f"download pdo 0x{p.index:04X} entry count", p.index, 0,
                     bytes([len(words)])))
    return cmds


def _assignment(index: int, pdos: list[PdoDesc], ca: bool) -> list[CoeInitCmd]:
    if not pdos:
        return []
    words = [struct.pack("<H", p.index) for p in pdos]
    if ca:
        return [_cmd(f"download pdo 0x{index:04X} index", index, 0,
                     bytes([len(words), 0]) + b"".join(words), complete_access=True)]
    cmds = [_cmd(f"download pdo 0x{index:04X}:{i:02X} index", index, i, w)
            for i, w in enumerate(words, start=1)]
    cmds.append(_cmd(f"download pdo 0x{index:04X} count", index, 0, bytes([len(words)])))
    return cmds
