"""SyncManager behaviour of an emulated ESC, as the EtherCAT side sees it.

Each SM is 8 register bytes at 0x0800 + 8·n (start, length, control, status, activate, PDI
control; ``docs/protocol-notes.md`` §2-§3):

* **mailbox** (control bits 1:0 = 10, one buffer): a write is taken only while the buffer is
  empty, and writing its last byte makes it *full* (status bit 3); a read is served only
  while it is full, and reading the last byte empties it.  Anything else gets no working
  counter, which is how masters learn "try later".
* **buffered** (bits 1:0 = 00, three buffers): the master always addresses ``start ..
  start + length - 1``; the ESC keeps the newest complete buffer.  The emulated firmware
  consumes writes at once, so one buffer in memory gives the same view from the wire.
  Writing the last byte is a complete write: it feeds the SM watchdog.
* **repeat** (activate bit 1 toggled by the master): the slave posts its last mailbox
  message again and acknowledges in PDI control bit 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from ecatcfg.esc import (SM_DIR_ECAT_WRITES, SM_DIR_MASK, SM_MODE_MAILBOX, SM_MODE_MASK,
                         SM_PDI_REPEAT_ACK, SM_SIZE, SM_STATUS_BUFFER_NONE, SM_STATUS_MAILBOX_FULL,
                         SM_STATUS_READ_EVENT, SM_STATUS_WRITE_EVENT, SmConfig, sm_register)


class SmKind(Enum):
    MAILBOX_OUT = "mailbox out"        # master -> slave (SM0)
    MAILBOX_IN = "mailbox in"          # slave -> master (SM1)
    OUTPUTS = "outputs"
    INPUTS = "inputs"


@dataclass(slots=True)
class SmState:
    """One SM as configured by the master, plus the buffer state the ESC keeps."""

    number: int
    start: int = 0
    length: int = 0
    control: int = 0
    enabled: bool = False
    full: bool = False
    read_event: bool = False            # status bit 1: the buffer was completely read
    repeat_request: bool = False

    @property
    def end(self) -> int:
        return self.start + self.length

    @property
    def is_mailbox(self) -> bool:
        return self.control & SM_MODE_MASK == SM_MODE_MAILBOX

    @property
    def master_writes(self) -> bool:
        return self.control & SM_DIR_MASK == SM_DIR_ECAT_WRITES

    @property
    def kind(self) -> SmKind:
        if self.is_mailbox:
            return SmKind.MAILBOX_OUT if self.master_writes else SmKind.MAILBOX_IN
        return SmKind.OUTPUTS if self.master_writes else SmKind.INPUTS

    @property
    def active(self) -> bool:
        return self.enabled and self.length > 0

    def covers(self, address: int, length: int) -> bool:
        return self.active and address < self.end and address + length > self.start

    def load(self, mem: bytearray) -> None:
        """Read the configuration the master wrote into the SM's registers."""
        cfg = SmConfig.from_bytes(mem[sm_register(self.number):sm_register(self.number)
                                      + SM_SIZE])
        changed = (cfg.start, cfg.length, cfg.control) != (self.start, self.length,
                                                           self.control)
        if changed or not cfg.enable:
            self.full = False               # a disabled or moved mailbox starts empty
            self.read_event = False
        self.start, self.length, self.control, self.enabled = (
            cfg.start, cfg.length, cfg.control, cfg.enable)

    def store_status(self, mem: bytearray) -> None:
        """Keep the status byte (read-only for the master) in step with the buffer."""
        reg = sm_register(self.number)
        if self.is_mailbox:
            # A full mailbox has its buffer written (bit 0) and full (bit 3); the ENIs'
            # mailbox-state FMMU maps bit 0 of SM1's status (docs/eni-exports.md §3).
            # Once emptied by a complete read, a real ESC shows the read event (bit 1):
            # LAN9252 slaves read 0x02 on SM0 after the firmware took a message and on
            # SM1 after the master read a reply (ethercrab-rs/ethercrab
            # dumps/soem-single-lan9252.pcapng).
            mem[reg + 5] = (SM_STATUS_MAILBOX_FULL | SM_STATUS_WRITE_EVENT if self.full
                            else SM_STATUS_READ_EVENT if self.read_event else 0)
        elif not mem[reg + 5]:
            mem[reg + 5] = SM_STATUS_BUFFER_NONE
        pdi = mem[reg + 7] & ~SM_PDI_REPEAT_ACK
        mem[reg + 7] = pdi | (SM_PDI_REPEAT_ACK if self.repeat_request else 0)
