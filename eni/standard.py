"""The standard register set-up of an EtherCAT slave, as real configurators write it.

The master's own list and each slave's register InitCmds, in the order and with the
comments of TwinCAT and EC-Engineer exports (``docs/eni-exports.md`` §2–§3, cited below as
"eni-exports §N"): a runtime filters a slave's list by transition and runs it in file order,
so the list below is arranged so that every transition's commands come out in the right
order, e.g. for I→P: INIT + check, EEPROM identity checks, station address, mailbox SMs,
clear process-data SMs, mailbox-state FMMU, EEPROM to PDI, PREOP + check.  Before the
station address is set the commands are auto-increment addressed (APxx, ADP = position),
afterwards configured-address (FPxx, ADP = station address).

One rule, two users: the compiler (``compiler/initcmds.py``) describes a slave from its ESI
and the topology, :mod:`ecatcfg.eni.derive` from what a partial ENI says of it; both give
a :class:`SlaveSetup` to :func:`slave_init_cmds`.

The 2011 ENI schema has no ``Timeout`` on these commands: poll timeouts go into
``Validate/Timeout``; how long to keep retrying a state write is left to the runtime.
"""

from __future__ import annotations

import struct

from ecatcfg.eni.plan import DcPlan, InitCmd, Validate
from ecatcfg.esc import (AL_ERROR_ACK, SII_PRODUCT_CODE, SII_VENDOR_ID, SM1_STATUS,
                         AlState, Cmd, FmmuConfig, FmmuType, Reg, SmConfig, Transition as T,
                         eeprom_read_request, fmmu_register, sm_register)
from ecatcfg.esc import WATCHDOG_DIVIDER_DEFAULT, WATCHDOG_TIME_DEFAULT
from ecatcfg.record import field, record

# Default state-machine timeouts (ms) when the ESI's Info/StateMachine/Timeout gives none:
# the values TwinCAT and EC-Engineer write.
PREOP_TIMEOUT = 3000
SAFEOP_OP_TIMEOUT = 10000
BACK_TO_INIT_TIMEOUT = 5000
BACK_TO_SAFEOP_TIMEOUT = 200
EEPROM_TIMEOUT = 100
PREOP_RETRIES = 300          # both tools retry the PREOP request this often


@record(frozen=True)
class PdSm:
    """A process-data SyncManager as the set-up writes it: its register image (length 0:
    written disabled, see :func:`pd_sm_config`), whether it carries outputs, and whether
    it is enabled only in OP (ESI ``Sm/@OpOnly``: set in SAFEOP->OP, cleared in OP->SAFEOP)."""

    number: int
    outputs: bool
    config: SmConfig
    op_only: bool = False


@record(frozen=True)
class Watchdogs:
    """The ESC watchdog registers as the set-up writes them, in register units: the divider
    (0x0400; time base (divider + 2) x 40 ns, ``esc.watchdog_base_ns``), the PDI watchdog
    (0x0410) and the SM watchdog (0x0420) in that base, 0 = off.  The defaults are the ESC's
    power-on values, which TwinCAT and EC-Engineer write for drives (eni-exports §3)."""

    divider: int = WATCHDOG_DIVIDER_DEFAULT
    pdi: int = WATCHDOG_TIME_DEFAULT
    sm: int = WATCHDOG_TIME_DEFAULT


@record(frozen=True)
class SlaveSetup:
    """What the standard set-up of one slave depends on."""

    position: int                             # auto-increment position (0, 1, ...)
    phys_addr: int                            # station address to set
    vendor_id: int                            # checked in the EEPROM in INIT->PREOP
    product_code: int
    alias: int | None = None                  # station alias to check, if any
    # Mailbox SyncManagers ((number, image) out, (number, image) in), if it has a mailbox.
    mailbox: tuple[tuple[int, SmConfig], tuple[int, SmConfig]] | None = None
    bootstrap: tuple[SmConfig, SmConfig] | None = None   # SM0/SM1 for BOOT
    pd_sms: list[PdSm] = field(default_factory=list)     # in number order
    fmmus: list[tuple[FmmuConfig, str]] = field(default_factory=list)  # FMMU 0, 1, ...
    dc: DcPlan | None = None
    assign_activate: int = 0                  # 0x0980 with DC
    # The ESC mirrors AL control into AL status (ESC configuration 0x0141 bit 0): a state
    # request must not carry the error-acknowledge bit, which would read back as the error
    # flag (docs/protocol-notes.md §2).
    device_emulation: bool = False
    # State-machine timeouts (ms): ESI Info/StateMachine/Timeout, else the tools' defaults.
    preop_timeout: int = 0
    safeop_op_timeout: int = 0
    back_to_init_timeout: int = 0
    back_to_safeop_timeout: int = 0
    # Watchdog registers to write in INIT->PREOP; None: none written (the ESC keeps its own).
    watchdog: Watchdogs | None = None


def pd_fmmu(logical_bit: int, bits: int, physical_start: int, kind: FmmuType) -> FmmuConfig:
    """The FMMU that maps ``bits`` of process data at logical bit address ``logical_bit``
    onto a SyncManager's memory at ``physical_start`` (bit 0): bit-sized data starts at the
    bit where it lies in the logical byte (ETG.1000.4 FMMU registers 0x0600 + 16·n)."""
    first = logical_bit % 8
    return FmmuConfig(logical_bit // 8, (first + bits + 7) // 8, first, (first + bits - 1) % 8,
                      physical_start, 0, kind)


def mailbox_state_fmmu(start_addr: int, bit: int) -> FmmuConfig:
    """The FMMU that copies a slave's mailbox-full flag (SM1 status) into bit ``bit`` of the
    master's mailbox-state bytes at logical ``start_addr`` (ENI ``Master/MailboxStates``)."""
    return FmmuConfig(start_addr + bit // 8, 1, bit % 8, bit % 8, SM1_STATUS, 0,
                      FmmuType.READ)


def pd_sm_config(start: int, bits: int, control: int) -> SmConfig:
    """A process-data SM image: length = the assigned PDOs' size; an unused SM is written
    disabled with control byte 0 (TwinCAT, EL4002 SM3 ``8011000000000000``)."""
    length = (bits + 7) // 8
    if not length:
        return SmConfig(start, 0, 0, False)
    return SmConfig(start, length, control, True)



def master_init_cmds() -> list[InitCmd]:
    """The twelve commands every TwinCAT and EC-Engineer export starts with (eni-exports §2)."""
    def bwr(comment: str, ado: int, data: bytes | None = None, length: int = 0,
            transitions: list[T] | None = None) -> InitCmd:
        return InitCmd(transitions or [T.IP], comment, Cmd.BWR, len(data) if data else length,
                       adp=0, ado=ado, data=data, retries=3, requires="cycle", before_slave=True)

    count = [InitCmd([T.IP], "read slave count", Cmd.BRD, 2, adp=0, ado=Reg.AL_STATUS,
                     data=bytes(2), retries=0, requires="cycle", before_slave=True)
             for _ in range(2)]
    return count + [
        bwr("enable ECAT IRQ", Reg.ECAT_EVENT_MASK, b"\x04\x00"),
        bwr("clear configured addresses", Reg.STATION_ADDRESS, bytes(2)),
        bwr("clear crc register", Reg.RX_ERROR_COUNTER, bytes(8)),
        bwr("clear fmmu", Reg.FMMU0, length=256, transitions=[T.IP, T.PI, T.BI, T.SI, T.OI]),
        bwr("clear sm", Reg.SM0, length=256),
        bwr("clear dc system time", Reg.DC_SYSTEM_TIME, length=32),
        bwr("clear dc cycle cfg", Reg.DC_CYCLIC_UNIT_CONTROL + 1, b"\x00"),
        bwr("reset dc speed", Reg.DC_SPEED_COUNTER_START, b"\x00\x10"),
        bwr("configure dc filter", Reg.DC_TIME_FILTER, b"\x00\x0c"),
        bwr("en/disable second physical address", Reg.DL_CONTROL_2, b"\x00"),
    ]


class _SlaveCmds:
    """Collects one slave's commands; ``ap``/``fp`` pick the addressing.  Also what the
    parts of :func:`slave_init_cmds` share: the slave's timeouts, its process-data
    SyncManagers and FMMUs, and whether its state requests acknowledge errors."""

    def __init__(self, slave: SlaveSetup) -> None:
        self.slave = slave
        self.auto = (-slave.position) & 0xFFFF
        self.phys = slave.phys_addr
        self.cmds: list[InitCmd] = []
        self.preop_to = slave.preop_timeout or PREOP_TIMEOUT
        self.safeop_to = slave.safeop_op_timeout or SAFEOP_OP_TIMEOUT
        self.init_to = slave.back_to_init_timeout or BACK_TO_INIT_TIMEOUT
        self.back_safeop_to = slave.back_to_safeop_timeout or BACK_TO_SAFEOP_TIMEOUT
        # State requests acknowledge errors where firmware answers them: a slave with a
        # mailbox (TwinCAT and EC-Engineer write 0x0012 to those, 0x0002 to the others;
        # eni-exports §3), unless its ESC mirrors AL control, which shows the acknowledge
        # bit as an error.
        self.ack = slave.mailbox is not None and not slave.device_emulation
        self.boot = [T.IB] if slave.bootstrap else []      # INIT->BOOT shares I->P's start
        self.to_init_boot = [T.BI] if slave.bootstrap else []
        self.pd = {sm.number: sm for sm in slave.pd_sms}
        self.pd_numbers = sorted(self.pd)
        self.op_only = {n for n, sm in self.pd.items() if sm.op_only}

    def ap(self, transitions: list[T], comment: str, cmd: Cmd, ado: int, data: bytes, *,
           cnt: int | None = None, validate: Validate | None = None,
           requires: str | None = None) -> None:
        self._add(self.auto, transitions, comment, cmd, ado, data, cnt, validate, requires)

    def fp(self, transitions: list[T], comment: str, cmd: Cmd, ado: int, data: bytes, *,
           cnt: int | None = None, validate: Validate | None = None,
           requires: str | None = None) -> None:
        self._add(self.phys, transitions, comment, cmd, ado, data, cnt, validate, requires)

    def _add(self, adp: int, transitions: list[T], comment: str, cmd: Cmd, ado: int,
             data: bytes, cnt: int | None, validate: Validate | None,
             requires: str | None) -> None:
        self.cmds.append(InitCmd(transitions, comment, cmd, len(data), adp=adp, ado=ado,
                                 data=data, cnt=cnt, retries=3, validate=validate,
                                 requires=requires))


def _al(state: AlState, ack: bool) -> bytes:
    return struct.pack("<H", state | (AL_ERROR_ACK if ack else 0))


def _status(state: AlState, mask: int, timeout: int) -> Validate:
    """Validate the 6 bytes AL status + AL status code (0x0130..0x0135)."""
    return Validate(bytes([state, 0, 0, 0, 0, 0]), bytes([mask, 0, 0, 0, 0, 0]), timeout)


def slave_init_cmds(slave: SlaveSetup) -> list[InitCmd]:
    """The slave's register InitCmds for every transition (eni-exports §3).  A runtime runs
    each transition's commands in list order, so the parts below interleave: each part adds
    the commands of several transitions at the place each transition needs them."""
    c = _SlaveCmds(slave)
    _back_to_init(c)
    _identity_and_address(c)
    _mailbox_and_cleared_sms(c)
    _op_only_sms(c)
    _process_data(c)
    _going_down(c)
    _preop_and_boot_requests(c)
    _safeop_and_op_requests(c)
    return c.cmds


def _back_to_init(c: _SlaveCmds) -> None:
    """Back to INIT from any state (eni-exports §3 PI/BI/SI/OI)."""
    c.ap([T.PI, *c.to_init_boot, T.SI, T.OI], "set device state to INIT",
         Cmd.APWR, Reg.AL_CONTROL, _al(AlState.INIT, c.ack), requires="cycle")
    if c.slave.dc:
        c.ap([T.SI, T.OI], "clear DC activation", Cmd.APWR, Reg.DC_CYCLIC_UNIT_CONTROL,
             bytes(2), requires="cycle")
    c.ap([T.PI, T.SI, T.OI], "check device state for INIT", Cmd.APRD, Reg.AL_STATUS, bytes(2),
         validate=Validate(b"\x01\x00", b"\x0f\x00", c.init_to), requires="cycle")
    if c.slave.bootstrap:
        c.ap([T.BI], "check device state for INIT", Cmd.APRD, Reg.AL_STATUS, bytes(2),
             validate=Validate(b"\x01\x00", b"\x0f\x00", 2 * c.init_to), requires="cycle")


def _identity_and_address(c: _SlaveCmds) -> None:
    """INIT -> PREOP: INIT and its check, the identity in the EEPROM, the alias, the
    station address and the watchdogs (eni-exports §3 I→P); the PREOP request of S→P and
    O→P."""
    slave = c.slave
    c.ap([T.IP, *c.boot], "set device state to INIT", Cmd.APWR, Reg.AL_CONTROL,
         _al(AlState.INIT, c.ack), cnt=1, requires="cycle")
    c.ap([T.IP, *c.boot], "check device state for INIT", Cmd.APRD, Reg.AL_STATUS, bytes(2),
         cnt=1, validate=Validate(b"\x01\x00", b"\x0f\x00", c.preop_to), requires="cycle")
    c.ap([T.IP], "assign EEPROM to ECAT", Cmd.APWR, Reg.EEPROM_CONFIG, b"\x00", cnt=1,
         requires="cycle")
    for comment, word, value in (("check vendor id", SII_VENDOR_ID, slave.vendor_id),
                                 ("check product code", SII_PRODUCT_CODE, slave.product_code)):
        c.ap([T.IP], comment, Cmd.APWR, Reg.EEPROM_CONTROL, eeprom_read_request(word), cnt=1)
        c.ap([T.IP], comment, Cmd.APRD, Reg.EEPROM_DATA, bytes(4), cnt=1, requires="cycle",
             validate=Validate(struct.pack("<I", value or 0), None, EEPROM_TIMEOUT))
    if slave.alias is not None:
        c.ap([T.IP], "check station alias", Cmd.APRD, Reg.STATION_ALIAS, bytes(2), cnt=1,
             requires="cycle",
             validate=Validate(struct.pack("<H", slave.alias), None, EEPROM_TIMEOUT))
    c.ap([T.IP, *c.boot], "set physical address", Cmd.APWR, Reg.STATION_ADDRESS,
         struct.pack("<H", slave.phys_addr), cnt=1, requires="cycle")
    if slave.watchdog is not None:
        # Right after the address, FPWR, no Requires (EC-Engineer's Elmo and TwinCAT's
        # Copley exports: eni-exports §3 I->P).
        for comment, ado, value in (
                ("set watchdog divider", Reg.WATCHDOG_DIVIDER, slave.watchdog.divider),
                ("set PDI watchdog", Reg.WATCHDOG_PDI, slave.watchdog.pdi),
                ("set SM watchdog", Reg.WATCHDOG_SM, slave.watchdog.sm)):
            c.fp([T.IP], comment, Cmd.FPWR, ado, struct.pack("<H", value), cnt=1)
    c.fp([T.SP, T.OP], "set device state to PREOP", Cmd.FPWR, Reg.AL_CONTROL,
         _al(AlState.PREOP, c.ack), requires="cycle")
    c.cmds[-1].retries = PREOP_RETRIES


def _mailbox_and_cleared_sms(c: _SlaveCmds) -> None:
    """INIT -> PREOP (and BOOT): the mailbox SyncManagers, cleared on the way down; DC
    switched off; the process-data SyncManagers cleared until P→S sets them."""
    slave, bootstrap = c.slave, c.slave.bootstrap
    if slave.mailbox is not None:
        c.fp([T.IP, *c.boot, T.PI, T.SI, T.OI], "clear sm 0/1 (mailbox out/in)", Cmd.FPWR,
             Reg.SM0, bytes(16))
        if bootstrap:
            c.ap([T.BI], "clear sm 0/1 (mailbox out/in)", Cmd.APWR, Reg.SM0, bytes(16))
        for (n, cfg), label in zip(slave.mailbox, ("mailbox out", "mailbox in")):
            c.fp([T.IP], f"set sm {n} ({label})", Cmd.FPWR, sm_register(n), cfg.to_bytes(),
                 cnt=1)
        if bootstrap:
            for n, (cfg, label) in enumerate(zip(bootstrap, ("bootstrap out", "bootstrap in"))):
                c.fp([T.IB], f"set sm {n} ({label})", Cmd.FPWR, sm_register(n), cfg.to_bytes(),
                     cnt=1)
    if slave.dc:
        c.fp([T.IP, T.PP], "clear DC activation", Cmd.FPWR, Reg.DC_CYCLIC_UNIT_CONTROL,
             bytes(2), requires="cycle")
    if c.pd_numbers:
        first, last = c.pd_numbers[0], c.pd_numbers[-1]
        c.fp([T.IP, T.SP, T.SI, T.OP, T.OI], "clear sms", Cmd.FPWR, sm_register(first),
             bytes(8 * (last - first + 1)))


def _op_only_sms(c: _SlaveCmds) -> None:
    """SAFEOP <-> OP for SMs the ESI marks OpOnly (outputs enabled only in OP, e.g.
    EL2008)."""
    for n in c.pd_numbers:
        if n in c.op_only:
            c.fp([T.OS], f"clear {_kind(c.pd[n])} sm", Cmd.FPWR, sm_register(n), bytes(8))
    for n in c.pd_numbers:
        if n in c.op_only:
            c.fp([T.SO], f"set sm {n} ({_kind(c.pd[n])}s)", Cmd.FPWR, sm_register(n),
                 c.pd[n].config.to_bytes(), cnt=1)


def _process_data(c: _SlaveCmds) -> None:
    """PREOP -> SAFEOP: DC, process-data SMs, FMMUs (eni-exports §3 P→S, §6); the
    mailbox-state FMMU in I→P."""
    dc = c.slave.dc
    if dc:
        c.fp([T.PS], "set DC cycle time", Cmd.FPWR, Reg.DC_SYNC0_CYCLE_TIME,
             struct.pack("<II", dc.cycle_time0, dc.cycle_time1), cnt=1, requires="cycle")
        # Zero placeholder: the master writes the real start time at run time.
        c.fp([T.PS], "set DC start time", Cmd.FPWR, Reg.DC_START_TIME_CYCLIC, bytes(8), cnt=1,
             requires="cycle")
        c.fp([T.PS], "set DC activation", Cmd.FPWR, Reg.DC_CYCLIC_UNIT_CONTROL,
             struct.pack("<H", c.slave.assign_activate), cnt=1, requires="cycle")
        c.fp([T.PS], "set DC latch cfg", Cmd.FPWR, Reg.DC_LATCH0_CONTROL, bytes(2),
             requires="cycle")
    for n in c.pd_numbers:
        if n not in c.op_only:
            c.fp([T.PS], f"set sm {n} ({_kind(c.pd[n])}s)", Cmd.FPWR, sm_register(n),
                 c.pd[n].config.to_bytes(), cnt=1)
    # In FMMU order, whatever the transition (TwinCAT: an ESI that lists MBoxState first
    # gives "set fmmu 0 (mailbox state)" IP, then "set fmmu 1 (outputs)" PS ...).
    for i, (f, label) in enumerate(c.slave.fmmus):
        c.fp([T.IP, *c.boot] if label == "mailbox state" else [T.PS], f"set fmmu {i} ({label})",
             Cmd.FPWR, fmmu_register(i), f.to_bytes(), cnt=1)


def _going_down(c: _SlaveCmds) -> None:
    """Going down (eni-exports §3 OS, SP/OP, SI/OI, PI): SAFEOP requested from OP, FMMUs
    and DC cleared, PREOP checked."""
    c.fp([T.OS], "set device state to SAFEOP", Cmd.FPWR, Reg.AL_CONTROL,
         _al(AlState.SAFEOP, False), requires="cycle")
    for i, (_, label) in enumerate(c.slave.fmmus):
        c.fp([T.PI, *c.to_init_boot, T.SI, T.OI] if label == "mailbox state"
             else [T.SP, T.SI, T.OP, T.OI], f"clear fmmu {i}", Cmd.FPWR, fmmu_register(i),
             bytes(16))
    if c.slave.dc:
        c.fp([T.SP, T.OP], "clear DC activation", Cmd.FPWR, Reg.DC_CYCLIC_UNIT_CONTROL,
             bytes(2), requires="cycle")
    c.fp([T.SP, T.OP], "check device state for PREOP", Cmd.FPRD, Reg.AL_STATUS, bytes(6),
         validate=_status(AlState.PREOP, 0x0F, c.init_to), requires="cycle")


def _preop_and_boot_requests(c: _SlaveCmds) -> None:
    """End of INIT -> PREOP: EEPROM to the slave's controller, PREOP requested and checked;
    BOOT likewise."""
    c.fp([T.IP, *c.boot], "assign EEPROM to PDI", Cmd.FPWR, Reg.EEPROM_CONFIG, b"\x01", cnt=1,
         requires="cycle")
    c.ap([T.II], "assign EEPROM back to ECAT", Cmd.APWR, Reg.EEPROM_CONFIG, b"\x00",
         requires="cycle")
    c.fp([T.IP], "set device state to PREOP", Cmd.FPWR, Reg.AL_CONTROL,
         _al(AlState.PREOP, c.ack), cnt=1, requires="cycle")
    c.cmds[-1].retries = PREOP_RETRIES
    c.fp([T.IP], "check device state for PREOP", Cmd.FPRD, Reg.AL_STATUS, bytes(6), cnt=1,
         validate=_status(AlState.PREOP, 0x1F, c.preop_to), requires="cycle")
    c.ap([T.IP, *c.to_init_boot], "assign EEPROM back to ECAT", Cmd.APWR,
         Reg.EEPROM_CONFIG, b"\x00", requires="cycle")
    if c.slave.bootstrap:
        c.fp([T.IB], "set device state to BOOT", Cmd.FPWR, Reg.AL_CONTROL,
             _al(AlState.BOOT, True), cnt=1, requires="cycle")
        c.fp([T.IB], "check device state for BOOT", Cmd.FPRD, Reg.AL_STATUS, bytes(6), cnt=1,
             validate=_status(AlState.BOOT, 0x1F, c.preop_to), requires="cycle")


def _safeop_and_op_requests(c: _SlaveCmds) -> None:
    """PREOP -> SAFEOP -> OP state requests, and the SAFEOP check of O→S."""
    c.fp([T.PS], "set device state to SAFEOP", Cmd.FPWR, Reg.AL_CONTROL,
         _al(AlState.SAFEOP, False), cnt=1, requires="cycle")
    c.fp([T.PS], "check device state for SAFEOP", Cmd.FPRD, Reg.AL_STATUS, bytes(6), cnt=1,
         validate=_status(AlState.SAFEOP, 0x1F, c.safeop_to), requires="cycle")
    c.fp([T.OS], "check device state for SAFEOP", Cmd.FPRD, Reg.AL_STATUS, bytes(6),
         validate=_status(AlState.SAFEOP, 0x0F, c.back_safeop_to), requires="cycle")
    c.fp([T.SO], "set device state to OP", Cmd.FPWR, Reg.AL_CONTROL, _al(AlState.OP, False),
         cnt=1, requires="cycle")
    c.fp([T.SO], "check device state for OP", Cmd.FPRD, Reg.AL_STATUS, bytes(6), cnt=1,
         validate=_status(AlState.OP, 0x1F, c.safeop_to), requires="cycle")


def _kind(sm: PdSm) -> str:
    return "output" if sm.outputs else "input"
