"""Register InitCmds: the master's own list and each slave's, in the order real configurators use.

The order and comments are those of TwinCAT and EC-Engineer exports (``docs/eni-exports.md``
§2–§3, cited below as "eni-exports §N"): a runtime filters a slave's list by transition and
runs it in file order, so the list below is arranged so that every transition's commands
come out in the right order, e.g. for I→P: INIT + check, EEPROM identity checks, station
address, mailbox SMs, clear process-data SMs, mailbox-state FMMU, EEPROM to PDI, PREOP +
check.  Before the station address is set the commands are auto-increment addressed (APxx,
ADP = position), afterwards configured-address (FPxx, ADP = station address).

The 2011 ENI schema has no ``Timeout`` on these commands: poll timeouts go into
``Validate/Timeout``; how long to keep retrying a state write is left to the runtime.
"""

from __future__ import annotations

import struct

from ecatcfg.compiler.layout import SlaveLayout, pd_bits
from ecatcfg.eni.plan import DcPlan, InitCmd, Validate
from ecatcfg.compiler.resolve import ResolvedSlave
from ecatcfg.esc import (AL_ERROR_ACK, SII_PRODUCT_CODE, SII_VENDOR_ID, AlState, Cmd,
                         Reg, SmConfig, Transition as T, eeprom_read_request, fmmu_register,
                         sm_register)

# Default state-machine timeouts (ms) when the ESI's Info/StateMachine/Timeout gives none:
# the values TwinCAT and EC-Engineer write.
PREOP_TIMEOUT = 3000
SAFEOP_OP_TIMEOUT = 10000
BACK_TO_INIT_TIMEOUT = 5000
BACK_TO_SAFEOP_TIMEOUT = 200
EEPROM_TIMEOUT = 100
PREOP_RETRIES = 300          # both tools retry the PREOP request this often


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
    """Collects one slave's commands; ``ap``/``fp`` pick the addressing."""

    def __init__(self, slave: ResolvedSlave) -> None:
        self.auto = (-slave.position) & 0xFFFF
        self.phys = slave.phys_addr
        self.cmds: list[InitCmd] = []

    def ap(self, transitions: list[T], comment: str, cmd: Cmd, ado: int, data: bytes, *,
           cnt: int | None = None, validate: Validate | None = None,
           requires: str | None = None) -> None:
        self.cmds.append(InitCmd(transitions, comment, cmd, len(data), adp=self.auto, ado=ado,
                                 data=data, cnt=cnt, retries=3, validate=validate,
                                 requires=requires))

    def fp(self, transitions: list[T], comment: str, cmd: Cmd, ado: int, data: bytes, *,
           cnt: int | None = None, validate: Validate | None = None,
           requires: str | None = None) -> None:
        self.cmds.append(InitCmd(transitions, comment, cmd, len(data), adp=self.phys, ado=ado,
                                 data=data, cnt=cnt, retries=3, validate=validate,
                                 requires=requires))


def _al(state: AlState, ack: bool) -> bytes:
    return struct.pack("<H", state | (AL_ERROR_ACK if ack else 0))


def _status(state: AlState, mask: int, timeout: int) -> Validate:
    """Validate the 6 bytes AL status + AL status code (0x0130..0x0135)."""
    return Validate(bytes([state, 0, 0, 0, 0, 0]), bytes([mask, 0, 0, 0, 0, 0]), timeout)


def slave_init_cmds(slave: ResolvedSlave, lay: SlaveLayout, dc: DcPlan | None,
                    assign_activate: int, bootstrap: tuple[SmConfig, SmConfig] | None
                    ) -> list[InitCmd]:
    dev = slave.device
    info = dev.info
    preop_to = (info and info.preop_timeout) or PREOP_TIMEOUT
    safeop_to = (info and info.safeop_op_timeout) or SAFEOP_OP_TIMEOUT
    init_to = (info and info.back_to_init_timeout) or BACK_TO_INIT_TIMEOUT
    back_safeop_to = (info and info.back_to_safeop_timeout) or BACK_TO_SAFEOP_TIMEOUT
    mailbox = [sm for sm in dev.sms if sm.is_mailbox]
    has_mbx = len(mailbox) >= 2
    boot = [T.IB] if bootstrap else []
    c = _SlaveCmds(slave)

    out, inp = pd_bits(slave)
    pd = [(n, bits) for n, bits in out + inp]
    pd_numbers = sorted(n for n, _ in pd)
    op_only = {sm.number for sm in dev.sms if sm.op_only}
    pd_fmmus = [(i, f, label) for i, (f, label) in enumerate(lay.fmmus)
                if label != "mailbox state"]
    mbx_fmmu = [(i, f) for i, (f, label) in enumerate(lay.fmmus) if label == "mailbox state"]

    # Back to INIT from any state (eni-exports §3 PI/BI/SI/OI).
    c.ap([T.PI, *([T.BI] if bootstrap else []), T.SI, T.OI], "set device state to INIT",
         Cmd.APWR, Reg.AL_CONTROL, _al(AlState.INIT, has_mbx), requires="cycle")
    if dc:
        c.ap([T.SI, T.OI], "clear DC activation", Cmd.APWR, Reg.DC_CYCLIC_UNIT_CONTROL,
             bytes(2), requires="cycle")
    c.ap([T.PI, T.SI, T.OI], "check device state for INIT", Cmd.APRD, Reg.AL_STATUS, bytes(2),
         validate=Validate(b"\x01\x00", b"\x0f\x00", init_to), requires="cycle")
    if bootstrap:
        c.ap([T.BI], "check device state for INIT", Cmd.APRD, Reg.AL_STATUS, bytes(2),
             validate=Validate(b"\x01\x00", b"\x0f\x00", 2 * init_to), requires="cycle")

    # INIT -> PREOP: identity, address, mailbox (eni-exports §3 I→P).
    c.ap([T.IP, *boot], "set device state to INIT", Cmd.APWR, Reg.AL_CONTROL,
         _al(AlState.INIT, has_mbx), cnt=1, requires="cycle")
    c.ap([T.IP, *boot], "check device state for INIT", Cmd.APRD, Reg.AL_STATUS, bytes(2), cnt=1,
         validate=Validate(b"\x01\x00", b"\x0f\x00", preop_to), requires="cycle")
    c.ap([T.IP], "assign EEPROM to ECAT", Cmd.APWR, Reg.EEPROM_CONFIG, b"\x00", cnt=1,
         requires="cycle")
    for comment, word, value in (("check vendor id", SII_VENDOR_ID, dev.vendor.id),
                                 ("check product code", SII_PRODUCT_CODE, dev.product_code)):
        c.ap([T.IP], comment, Cmd.APWR, Reg.EEPROM_CONTROL, eeprom_read_request(word), cnt=1)
        c.ap([T.IP], comment, Cmd.APRD, Reg.EEPROM_DATA, bytes(4), cnt=1, requires="cycle",
             validate=Validate(struct.pack("<I", value or 0), None, EEPROM_TIMEOUT))
    if slave.cfg.alias is not None:
        c.ap([T.IP], "check station alias", Cmd.APRD, Reg.STATION_ALIAS, bytes(2), cnt=1,
             requires="cycle",
             validate=Validate(struct.pack("<H", slave.cfg.alias), None, EEPROM_TIMEOUT))
    c.ap([T.IP, *boot], "set physical address", Cmd.APWR, Reg.STATION_ADDRESS,
         struct.pack("<H", slave.phys_addr), cnt=1, requires="cycle")
    c.fp([T.SP, T.OP], "set device state to PREOP", Cmd.FPWR, Reg.AL_CONTROL,
         _al(AlState.PREOP, has_mbx), requires="cycle")
    c.cmds[-1].retries = PREOP_RETRIES
    if has_mbx:
        c.fp([T.IP, *boot, T.PI, T.SI, T.OI], "clear sm 0/1 (mailbox out/in)", Cmd.FPWR, Reg.SM0,
             bytes(16))
        if bootstrap:
            c.ap([T.BI], "clear sm 0/1 (mailbox out/in)", Cmd.APWR, Reg.SM0, bytes(16))
        for sm, label in ((mailbox[0], "mailbox out"), (mailbox[1], "mailbox in")):
            c.fp([T.IP], f"set sm {sm.number} ({label})", Cmd.FPWR, sm_register(sm.number),
                 SmConfig(sm.start_address or 0, sm.mailbox_size, sm.mailbox_control,
                          True).to_bytes(), cnt=1)
        if bootstrap:
            for n, (cfg, label) in enumerate(zip(bootstrap, ("bootstrap out", "bootstrap in"))):
                c.fp([T.IB], f"set sm {n} ({label})", Cmd.FPWR, sm_register(n), cfg.to_bytes(),
                     cnt=1)
    if dc:
        c.fp([T.IP, T.PP], "clear DC activation", Cmd.FPWR, Reg.DC_CYCLIC_UNIT_CONTROL,
             bytes(2), requires="cycle")
    if pd_numbers:
        first, last = pd_numbers[0], pd_numbers[-1]
        c.fp([T.IP, T.SP, T.SI, T.OP, T.OI], "clear sms", Cmd.FPWR, sm_register(first),
             bytes(8 * (last - first + 1)))

    # SAFEOP <-> OP for SMs the ESI marks OpOnly (outputs enabled only in OP, e.g. EL2008).
    sm_data = {n: _pd_sm(slave, n, bits) for n, bits in pd}
    for n in pd_numbers:
        if n in op_only:
            c.fp([T.OS], f"clear {_kind(slave, n)} sm", Cmd.FPWR, sm_register(n), bytes(8))
    for n in pd_numbers:
        if n in op_only:
            c.fp([T.SO], f"set sm {n} ({_kind(slave, n)}s)", Cmd.FPWR, sm_register(n),
                 sm_data[n], cnt=1)

    # PREOP -> SAFEOP: DC, process-data SMs, FMMUs (eni-exports §3 P→S, §6).
    if dc:
        c.fp([T.PS], "set DC cycle time", Cmd.FPWR, Reg.DC_SYNC0_CYCLE_TIME,
             struct.pack("<II", dc.cycle_time0, dc.cycle_time1), cnt=1, requires="cycle")
        # Zero placeholder: the master writes the real start time at run time.
        c.fp([T.PS], "set DC start time", Cmd.FPWR, Reg.DC_START_TIME_CYCLIC, bytes(8), cnt=1,
             requires="cycle")
        c.fp([T.PS], "set DC activation", Cmd.FPWR, Reg.DC_CYCLIC_UNIT_CONTROL,
             struct.pack("<H", assign_activate), cnt=1, requires="cycle")
        c.fp([T.PS], "set DC latch cfg", Cmd.FPWR, Reg.DC_LATCH0_CONTROL, bytes(2),
             requires="cycle")
    for n in pd_numbers:
        if n not in op_only:
            c.fp([T.PS], f"set sm {n} ({_kind(slave, n)}s)", Cmd.FPWR, sm_register(n),
                 sm_data[n], cnt=1)
    for i, f, label in pd_fmmus:
        c.fp([T.PS], f"set fmmu {i} ({label})", Cmd.FPWR, fmmu_register(i), f.to_bytes(), cnt=1)
    for i, f in mbx_fmmu:
        c.fp([T.IP, *boot], f"set fmmu {i} (mailbox state)", Cmd.FPWR, fmmu_register(i),
             f.to_bytes(), cnt=1)

    # Going down (eni-exports §3 OS, SP/OP, SI/OI, PI).
    c.fp([T.OS], "set device state to SAFEOP", Cmd.FPWR, Reg.AL_CONTROL,
         _al(AlState.SAFEOP, False), requires="cycle")
    for i, _, _ in pd_fmmus:
        c.fp([T.SP, T.SI, T.OP, T.OI], f"clear fmmu {i}", Cmd.FPWR, fmmu_register(i),
             bytes(16))
    for i, _ in mbx_fmmu:
        c.fp([T.PI, *([T.BI] if bootstrap else []), T.SI, T.OI], f"clear fmmu {i}", Cmd.FPWR,
             fmmu_register(i), bytes(16))
    if dc:
        c.fp([T.SP, T.OP], "clear DC activation", Cmd.FPWR, Reg.DC_CYCLIC_UNIT_CONTROL,
             bytes(2), requires="cycle")
    c.fp([T.SP, T.OP], "check device state for PREOP", Cmd.FPRD, Reg.AL_STATUS, bytes(6),
         validate=_status(AlState.PREOP, 0x0F, init_to), requires="cycle")

    # End of INIT -> PREOP: EEPROM to the slave's controller, request PREOP.
    c.fp([T.IP, *boot], "assign EEPROM to PDI", Cmd.FPWR, Reg.EEPROM_CONFIG, b"\x01", cnt=1,
         requires="cycle")
    c.ap([T.II], "assign EEPROM back to ECAT", Cmd.APWR, Reg.EEPROM_CONFIG, b"\x00",
         requires="cycle")
    c.fp([T.IP], "set device state to PREOP", Cmd.FPWR, Reg.AL_CONTROL,
         _al(AlState.PREOP, has_mbx), cnt=1, requires="cycle")
    c.cmds[-1].retries = PREOP_RETRIES
    c.fp([T.IP], "check device state for PREOP", Cmd.FPRD, Reg.AL_STATUS, bytes(6), cnt=1,
         validate=_status(AlState.PREOP, 0x1F, preop_to), requires="cycle")
    c.ap([T.IP, *([T.BI] if bootstrap else [])], "assign EEPROM back to ECAT", Cmd.APWR,
         Reg.EEPROM_CONFIG, b"\x00", requires="cycle")
    if bootstrap:
        c.fp([T.IB], "set device state to BOOT", Cmd.FPWR, Reg.AL_CONTROL,
             _al(AlState.BOOT, True), cnt=1, requires="cycle")
        c.fp([T.IB], "check device state for BOOT", Cmd.FPRD, Reg.AL_STATUS, bytes(6), cnt=1,
             validate=_status(AlState.BOOT, 0x1F, preop_to), requires="cycle")

    # PREOP -> SAFEOP -> OP state requests.
    c.fp([T.PS], "set device state to SAFEOP", Cmd.FPWR, Reg.AL_CONTROL,
         _al(AlState.SAFEOP, False), cnt=1, requires="cycle")
    c.fp([T.PS], "check device state for SAFEOP", Cmd.FPRD, Reg.AL_STATUS, bytes(6), cnt=1,
         validate=_status(AlState.SAFEOP, 0x1F, safeop_to), requires="cycle")
    c.fp([T.OS], "check device state for SAFEOP", Cmd.FPRD, Reg.AL_STATUS, bytes(6),
         validate=_status(AlState.SAFEOP, 0x0F, back_safeop_to), requires="cycle")
    c.fp([T.SO], "set device state to OP", Cmd.FPWR, Reg.AL_CONTROL, _al(AlState.OP, False),
         cnt=1, requires="cycle")
    c.fp([T.SO], "check device state for OP", Cmd.FPRD, Reg.AL_STATUS, bytes(6), cnt=1,
         validate=_status(AlState.OP, 0x1F, safeop_to), requires="cycle")
    return c.cmds


def _kind(slave: ResolvedSlave, n: int) -> str:
    sm = next(s for s in slave.device.sms if s.number == n)
    return "output" if sm.type == "Outputs" else "input"


def _pd_sm(slave: ResolvedSlave, n: int, bits: int) -> bytes:
    """A process-data SM image: length = the assigned PDOs' size; an unused SM is written
    disabled with control byte 0 (TwinCAT, EL4002 SM3 ``8011000000000000``)."""
    sm = next(s for s in slave.device.sms if s.number == n)
    length = (bits + 7) // 8
    if not length:
        return SmConfig(sm.start_address or 0, 0, 0, False).to_bytes()
    return SmConfig(sm.start_address or 0, length, sm.control_byte or 0, True).to_bytes()
