"""The PDO assignment and mapping a slave holds now, read over CoE (``ecatcfg pdos``).

The slave is prepared as for ``ecatcfg sdo`` (``sdo_tool.mailbox_session``); then, with SDO
uploads of one subindex each (what every CoE slave answers, complete access or not):

1. the SyncManager communication types, 0x1C00:00 and 0x1C00:01..n (ETG.1000.6: 3 process
   data outputs, 4 process data inputs); a slave without 0x1C00 is read as SM2 outputs and
   SM3 inputs, the standard SyncManagers (ETG.2000 default);
2. the PDO assignment of each process-data SM, 0x1C10 + SM, subindex 0 and 1..n;
3. the mapping of each PDO assigned, subindex 0 and 1..n, each entry a UDINT of index
   (bits 16-31), subindex (8-15) and bit length (0-7) (CiA 301 PDO mapping).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from ecatcfg.esc import SM_COMM_TYPE, SM_PDO_ASSIGN, SM_TYPE_CODES
from ecatcfg.runtime.mailbox import ABORT_NO_OBJECT, ABORT_NO_SUBINDEX
from ecatcfg.runtime.master.lockstep import Job, Step
from ecatcfg.runtime.master.replay import TIMEOUT_MAILBOX, ApplyError, MailboxChannel, sdo_job
from ecatcfg.runtime.master.sdo_tool import SdoToolError, SlaveMailbox, mailbox_session
from ecatcfg.runtime.master.transport import Transport

OUTPUTS = SM_TYPE_CODES["Outputs"]
INPUTS = SM_TYPE_CODES["Inputs"]
# SM2 outputs, SM3 inputs: a slave without 0x1C00.
STANDARD_PROCESS_DATA_SMS = {2: OUTPUTS, 3: INPUTS}


@dataclass(frozen=True, slots=True)
class MappedEntry:
    """One entry of a PDO mapping: index 0 is a gap of ``bit_length`` bits."""

    index: int
    subindex: int
    bit_length: int

    @classmethod
    def from_word(cls, word: int) -> MappedEntry:
        return cls(word >> 16, (word >> 8) & 0xFF, word & 0xFF)


@dataclass(slots=True)
class HeldPdo:
    index: int
    entries: list[MappedEntry] = field(default_factory=list)

    @property
    def bit_length(self) -> int:
        return sum(e.bit_length for e in self.entries)


@dataclass(slots=True)
class HeldAssignment:
    """The PDOs one process-data SyncManager has assigned (object 0x1C10 + ``sm``)."""

    sm: int
    sm_type: int                   # 3 outputs, 4 inputs
    pdos: list[HeldPdo] = field(default_factory=list)

    @property
    def assign_index(self) -> int:
        return SM_PDO_ASSIGN + self.sm

    @property
    def bit_length(self) -> int:
        return sum(p.bit_length for p in self.pdos)


def read_pdos(transport: Transport, position: int, *, timeout: float = TIMEOUT_MAILBOX,
              info: SlaveMailbox | None = None) -> list[HeldAssignment]:
    """The assignment and mapping of every process-data SM of the slave at ``position``."""
    result: list[HeldAssignment] = []
    info = info if info is not None else SlaveMailbox(position)

    def work(channel: MailboxChannel, size: int, counter: Callable[[], int]) -> Job:
        try:
            result.extend((yield from held_pdos(channel, size, counter, timeout)))
        except ApplyError as exc:
            raise SdoToolError(f"slave {position}: {exc}",
                               abort_code=exc.abort_code) from None

    mailbox_session(transport, position, work, info)
    return result


def held_pdos(channel: MailboxChannel, size: int, counter: Callable[[], int],
              timeout: float = TIMEOUT_MAILBOX) -> Step[list[HeldAssignment]]:
    from ecatcfg.runtime.master.sdo_client import SdoUpload

    def upload(index: int, sub: int) -> Step[int]:
        t = SdoUpload(index, sub, False, size, counter)
        yield from sdo_job(channel, t, None, f"SDO upload 0x{index:04X}:{sub:02X}", timeout)
        return int.from_bytes(t.result, "little")

    try:
        count = yield from upload(SM_COMM_TYPE, 0)
        types: dict[int, int] = {}
        for sm in range(count):
            types[sm] = yield from upload(SM_COMM_TYPE, sm + 1)
    except ApplyError as error:
        if error.abort_code not in (ABORT_NO_OBJECT, ABORT_NO_SUBINDEX):
            raise
        types = dict(STANDARD_PROCESS_DATA_SMS)
    out: list[HeldAssignment] = []
    for sm, sm_type in types.items():
        if sm_type not in (OUTPUTS, INPUTS):
            continue
        held = HeldAssignment(sm, sm_type)
        n = yield from upload(SM_PDO_ASSIGN + sm, 0)
        for k in range(1, n + 1):
            pdo = HeldPdo((yield from upload(SM_PDO_ASSIGN + sm, k)))
            entries = yield from upload(pdo.index, 0)
            for j in range(1, entries + 1):
                pdo.entries.append(MappedEntry.from_word((yield from upload(pdo.index, j))))
            held.pdos.append(pdo)
        out.append(held)
    return out
