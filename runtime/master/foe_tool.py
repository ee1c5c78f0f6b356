"""One FoE file transfer with one slave of a line no other master is driving (``ecatcfg foe``).

There is no ENI here: everything comes from the slave's own SII, as a master finds it while
scanning (ETG.2010): identity (words 0x08-0x0E), bootstrap mailbox (0x14-0x17: receive
offset, size, send offset, size), standard mailbox (0x18-0x1B), protocols (0x1C, FoE =
0x08).  The session:

1. count the slaves, read the AL status of the one asked for and its SII (the EEPROM
   belongs to EtherCAT while reading); refuse a slave without FoE in word 0x1C;
2. give it a station address when it has none (as ``ecatcfg sdo`` does);
3. bring it to INIT (a slave in BOOT or PREOP and above leaves its state: SyncManagers
   change only in INIT), write SM0/SM1 as the mailbox of the target state, control 0x26 /
   0x22 and enabled (the bootstrap mailbox for BOOT, as TwinCAT's IB commands write it:
   "set sm 0/1 (bootstrap out/in)"), hand the EEPROM to the PDI, request BOOT (3) or
   PREOP (2) and wait for it;
4. empty SM1, then the transfer (``foe_client.py``) with a deadline per reply;
5. back to INIT (a boot loader starts the new firmware only after it left BOOT; the next
   power-on runs it), then the identity is read again from the SII: the "after" of the
   report (a device shows a new revision there once it has been powered off and on).

The target state: BOOT when the SII gives a bootstrap mailbox, else PREOP; ``state``
overrides it.  BOOT is refused by a slave without a boot loader (AL status code 0x0013).
"""

from __future__ import annotations

import struct

from ecatcfg.runtime.clock import monotonic
from ecatcfg.eni.plan import MailboxArea, MailboxPlan
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (MAILBOX_PROTOCOL_BITS, SII_BOOTSTRAP_MAILBOX,
                         SII_MAILBOX_PROTOCOLS, SII_REVISION, SII_STD_MAILBOX, SII_VENDOR_ID,
                         SM_CONTROL_MBOX_IN, SM_CONTROL_MBOX_OUT, AlState, Cmd, Reg, SmConfig)
from ecatcfg.record import field, record
from ecatcfg.runtime.foe import FOE_OVERHEAD
from ecatcfg.runtime.master.foe_client import (FoeRead, FoeTransferError, FoeWrite, Progress,
                                               ProgressHook)
from ecatcfg.runtime.master.foe_init import run_transfer
from ecatcfg.runtime.master.lockstep import Job, Step, run_jobs
from ecatcfg.runtime.master.replay import TIMEOUT_COMMAND, ApplyError, MailboxChannel
from ecatcfg.runtime.master.scan import count_slaves, sii_words
# The preparation steps ecatcfg sdo takes too (its module's helpers: one definition).
from ecatcfg.runtime.master.sdo_tool import (MailboxCounter, SdoToolError, SlaveMailbox,
                                             access, empty_sm1, protocol_names, request_state,
                                             station_address_of)
from ecatcfg.runtime.master.transport import Transport
from ecatcfg.runtime.wire import Datagram

TIMEOUT_FOE = 10.0          # s one reply may take (a boot loader erasing flash answers busy)


class FoeToolError(EcatcfgError):
    """The transfer could not be done; ``foe_code`` is the slave's FoE error code when it
    refused, ``al_code`` its AL status code when it refused a state."""

    def __init__(self, message: str, foe_code: int | None = None,
                 al_code: int | None = None) -> None:
        super().__init__(message)
        self.foe_code = foe_code
        self.al_code = al_code


@record(frozen=True)
class Identity:
    vendor_id: int
    product_code: int
    revision: int
    serial_no: int

    def as_dict(self) -> dict[str, int]:
        return {"vendor_id": self.vendor_id, "product_code": self.product_code,
                "revision": self.revision, "serial_no": self.serial_no}


@record
class FoeReport:
    """What one session did: for the command's output and tests."""

    position: int
    action: str                                # "write" / "read"
    name: str
    state: str = ""                            # BOOT / PREOP: where the transfer ran
    station_address: int = 0
    al_status_before: int = 0
    bootstrap: tuple[int, int, int, int] = (0, 0, 0, 0)
    mailbox: tuple[int, int] = (0, 0)          # SM0 / SM1 lengths used
    size: int = 0                              # file bytes moved
    packets: int = 0
    busy_replies: int = 0
    seconds: float = 0.0                       # the transfer (request to last ack)
    frames: int = 0                            # frames sent in the whole session
    identity_before: Identity | None = None
    identity_after: Identity | None = None
    data: bytes = b""                          # what a read returned
    progress: list[Progress] = field(default_factory=list)


def foe_transfer(transport: Transport, position: int, name: str, data: bytes | None = None,
                 *, password: int = 0, state: AlState | None = None,
                 timeout: float = TIMEOUT_FOE, progress: ProgressHook | None = None,
                 limit: int | None = None) -> FoeReport:
    """Write ``data`` into file ``name`` of the slave at ``position`` (``data is None``:
    read it; ``limit`` bounds a read).  Raises :class:`FoeToolError` naming the slave,
    the file and the FoE error code or refusal."""
    report = FoeReport(position, "read" if data is None else "write", name)
    n = count_slaves(transport)
    if not 0 <= position < n:
        raise FoeToolError(f"no slave at position {position}: the line has {n} "
                           f"slave{'s' if n != 1 else ''}"
                           + (f" (positions 0..{n - 1})" if n > 1 else ""))
    if state not in (None, AlState.BOOT, AlState.PREOP):
        raise FoeToolError(f"FoE runs in BOOT or PREOP, not {state}")

    def hook(p: Progress) -> None:
        report.progress.append(p)
        if progress is not None:
            progress(p)

    sent = transport.counters.frames_sent
    try:
        run_jobs(transport, [_session(report, data, password, state, timeout, hook, limit)])
    except SdoToolError as exc:
        raise FoeToolError(str(exc), al_code=exc.al_code) from None
    report.frames = transport.counters.frames_sent - sent
    return report


def _session(report: FoeReport, data: bytes | None, password: int, state: AlState | None,
             timeout: float, hook: ProgressHook, limit: int | None) -> Job:
    pos = report.position
    who = f"slave {pos}"
    adp = -pos & 0xFFFF
    deadline = monotonic() + TIMEOUT_COMMAND
    status = yield from access(Datagram.physical(Cmd.APRD, adp, Reg.AL_STATUS, 2), deadline,
                                f"{who}: reading the AL status (0x0130)")
    report.al_status_before = struct.unpack_from("<H", status.data)[0]
    report.identity_before = yield from _identity(adp, pos, who)
    sii_deadline = monotonic() + TIMEOUT_COMMAND
    try:
        boot = struct.unpack("<4H", (yield from sii_words(pos, SII_BOOTSTRAP_MAILBOX,
                                                          sii_deadline)))
        std = struct.unpack("<4H", (yield from sii_words(pos, SII_STD_MAILBOX, sii_deadline)))
        proto = yield from sii_words(pos, SII_MAILBOX_PROTOCOLS, sii_deadline)
    except ApplyError as exc:
        raise FoeToolError(str(exc)) from None
    report.bootstrap = (boot[0], boot[1], boot[2], boot[3])
    protocols = struct.unpack_from("<H", proto)[0]
    if not protocols & MAILBOX_PROTOCOL_BITS["FoE"]:
        raise FoeToolError(f"{who} does not support FoE: its SII lists the mailbox "
                           f"protocols 0x{protocols:04X} ({protocol_names(protocols)})")
    has_boot = boot[1] > 0 and boot[3] > 0
    target = state if state is not None else AlState.BOOT if has_boot else AlState.PREOP
    rx_start, rx_size, tx_start, tx_size = boot if target == AlState.BOOT else std
    if not rx_size or not tx_size:
        which = "bootstrap (words 0x14-0x17)" if target == AlState.BOOT else \
            "standard (words 0x18-0x1B)"
        raise FoeToolError(f"{who}: the SII gives no {which} mailbox for "
                           f"{target.name}")
    for what, size in (("receive", rx_size), ("send", tx_size)):
        if size <= FOE_OVERHEAD:
            raise FoeToolError(f"{who}: a {size}-byte {what} mailbox cannot carry FoE data")
    report.state = target.name
    report.mailbox = (rx_size, tx_size)

    address = yield from station_address_of(SlaveMailbox(pos), adp, who)
    report.station_address = address
    yield from request_state(address, AlState.INIT, who)
    sm0 = SmConfig(rx_start, rx_size, SM_CONTROL_MBOX_OUT, True)
    sm1 = SmConfig(tx_start, tx_size, SM_CONTROL_MBOX_IN, True)
    deadline = monotonic() + TIMEOUT_COMMAND
    yield from access(Datagram.physical(Cmd.FPWR, address, Reg.SM0,
                                         sm0.to_bytes() + sm1.to_bytes()),
                       deadline, f"{who}: writing SM0/SM1 ({target.name} mailbox, 0x0800)")
    yield from access(Datagram.physical(Cmd.FPWR, address, Reg.EEPROM_CONFIG, b"\x01"),
                       deadline, f"{who}: handing the SII EEPROM to the PDI (0x0500)")
    yield from request_state(address, target, who)

    plan = MailboxPlan(MailboxArea(rx_start, rx_size), MailboxArea(tx_start, tx_size),
                       protocols=["FoE"])
    channel = MailboxChannel(address, plan)
    yield from empty_sm1(SlaveMailbox(pos), channel)
    started = monotonic()
    t: FoeRead | FoeWrite
    if data is None:
        t = FoeRead(report.name, password, mbx_out_size=rx_size, mbx_in_size=tx_size,
                    counter=MailboxCounter(), progress=hook, limit=limit)
    else:
        t = FoeWrite(report.name, data, password, mbx_out_size=rx_size,
                     mbx_in_size=tx_size, counter=MailboxCounter(), progress=hook)
    what = f"FoE {report.action} of {report.name!r}"
    try:
        yield from run_transfer(channel, t, timeout, who, what)
    except FoeTransferError as exc:
        # Leave the slave as a firmware update leaves it: back in INIT.
        yield from request_state(address, AlState.INIT, who)
        raise FoeToolError(f"{who}, {what}: {exc}", foe_code=exc.code) from None
    report.seconds = monotonic() - started
    report.packets, report.busy_replies = t.packets, t.busy_replies
    if isinstance(t, FoeRead):
        report.data = t.result
        report.size = len(report.data)
    else:
        report.size = len(t.data)
    yield from request_state(address, AlState.INIT, who)
    deadline = monotonic() + TIMEOUT_COMMAND
    yield from access(Datagram.physical(Cmd.FPWR, address, Reg.EEPROM_CONFIG, b"\x00"),
                       deadline, f"{who}: taking the SII EEPROM back (0x0500)")
    report.identity_after = yield from _identity(adp, pos, who)


def _identity(adp: int, pos: int, who: str) -> Step[Identity]:
    """The identity in the SII (words 0x08-0x0F), read while EtherCAT owns the EEPROM."""
    deadline = monotonic() + TIMEOUT_COMMAND
    yield from access(Datagram.physical(Cmd.APWR, adp, Reg.EEPROM_CONFIG, b"\x00"),
                       deadline, f"{who}: taking the SII EEPROM (0x0500)")
    try:
        ids = yield from sii_words(pos, SII_VENDOR_ID, monotonic() + TIMEOUT_COMMAND)
        rev = yield from sii_words(pos, SII_REVISION, monotonic() + TIMEOUT_COMMAND)
    except ApplyError as exc:
        raise FoeToolError(str(exc)) from None
    vendor, product = struct.unpack("<II", ids)
    revision, serial = struct.unpack("<II", rev)
    return Identity(vendor, product, revision, serial)


def parse_password(text: str) -> int:
    """``--password``: hexadecimal, ``0x`` optional, 32 bits."""
    digits = text.lower().removeprefix("0x").replace("_", "")
    try:
        value = int(digits, 16)
    except ValueError:
        raise ValueError(f"{text!r} is not a hexadecimal password (e.g. 0x12345678)") from None
    if not 0 <= value <= 0xFFFFFFFF:
        raise ValueError(f"{text!r}: an FoE password is 32 bits")
    return value


__all__ = ["FoeReport", "FoeToolError", "Identity", "foe_transfer", "parse_password"]
