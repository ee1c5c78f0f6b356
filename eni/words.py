"""An ENI's InitCmds in words: what each register, CoE, EoE, SoE or FoE command does to the
slave.

``show`` lists them per transition, ``diff`` compares them, and ``apply`` names a failing
command by :func:`init_cmd_name`.  The words come from the register a command writes and its
bytes, decoded through ``esc.py``'s register images (``SmConfig``, ``FmmuConfig``), never
from the file's ``Comment`` (free text a tool may write in any language, or leave out).

- ``set sm 2 (outputs) 0x1100 len 6 ctrl 0x64``: a SyncManager's 8-byte image
  (ESC Section II 0x0800 + 8n); its kind from the control byte's mode and direction bits.
- ``clear sm 0; clear sm 1``, ``clear fmmu 0-15``: records written with zeros.
- ``set fmmu 0 (outputs) logical 0x01000000.0-0x01000005.7 -> 0x1100.0``: an FMMU's 16-byte
  image (0x0600 + 16n).
- ``request SAFEOP``, ``check state SAFEOP``: AL control 0x0120, AL status 0x0130.
- ``SDO 0x1C12:00 = 0``, ``SDO 0x1C12:01 = 0x1600``, ``SDO 0x1A00:01 = 0x6041:00 16 bit``,
  ``SDO 0x1C12:00 complete = 2: 0x1600, 0x1601``: CoE downloads (ETG.1000.6; an assignment
  entry is a PDO index, a mapping entry index << 16 | subindex << 8 | bit length).
- ``SoE write S-0-0001 (drive 0) = d0 07``: an SoE write request of an IDN's value
  (ETG.1000.6 SoE, IDN notation of ``esi/idn.py``), its data in wire order.
- ``FoE read 'cal.bin' (password 0x0000002A)``: an FoE read request (ETG.1000.6 FoE).
- Any other register write or read by the names of ``registers.py``, the one register table:
  ``set DL control byte 3 = 0x00``, ``set ECAT event mask = 0x0004``, ``clear DC latch0
  control, DC latch1 control``, ``read AL status``; watchdog times with their time at the
  default divider (``set SM watchdog 10000 (1000 ms at the default divider)``).
- Any other command: its name, register and data (``FPWR 0x0F00 = 0x00``).

A slave-to-slave copy (``CopyInfo``) in words names the variables its bits are in:
``copy 4 bits: sensors.Channel 1.Input (in 0.4) -> lamps.Channel 1-8.Output 3 (out 1.2)``;
a bit no variable holds is shown as its place only.
"""

from __future__ import annotations

from ecatcfg.eni.compare import compared
from ecatcfg.eni.plan import (CoeInitCmd, CopyInfo, CyclicCmd, EoeInitCmd, FoeInitCmd,
                              InitCmd, SoeInitCmd, Variable)
from ecatcfg.esc import (AL_ERROR_ACK, AL_ID_REQUEST, FMMU_SIZE, REGISTER_READS,
                         REGISTER_WRITES, RX_PDO_MAPPING, SM_DIR_ECAT_WRITES, SM_DIR_MASK,
                         SM_MODE_MAILBOX, SM_MODE_MASK, SM_PDO_ASSIGN_RANGE, SM_SIZE,
                         TX_PDO_MAPPING, Cmd, FmmuConfig, FmmuType, FoeOpCode, Reg, SmConfig,
                         WATCHDOG_DIVIDER_DEFAULT, al_state_name, fmmu_register,
                         sm_register, watchdog_base_ns)
from ecatcfg.esi.idn import VALUE_ELEMENT, WRITE_REQUEST, idn_text
from ecatcfg.registers import containing, covered

_SM_AREA = range(sm_register(0), sm_register(32))          # 32 SyncManagers
_FMMU_AREA = range(fmmu_register(0), fmmu_register(16))    # 16 FMMUs


def init_cmd_name(cmd: InitCmd) -> str:
    """How messages and the report name a register InitCmd: its ``Comment``, or, where the
    ENI gives none (``Comment`` is optional in ETG.2100's ``ECatCmdType``), its command and
    register (``APWR 0x0120``) or logical address, so a failure still says which one."""
    if cmd.comment.strip():
        return cmd.comment
    return command_address(cmd)


def command_address(cmd: InitCmd | CyclicCmd) -> str:
    """``APWR 0x0120``, ``LWR logical 0x00010000``, ``command 99``."""
    name = command_name(cmd.cmd)
    if cmd.ado is not None:
        return f"{name} 0x{cmd.ado:04X}"
    if cmd.addr is not None:
        return f"{name} logical 0x{cmd.addr:08X}"
    return name


def command_name(cmd: int) -> str:
    """A datagram command by its ETG.1000.4 name, or ``command N`` for an unknown code."""
    try:
        return Cmd(cmd).name
    except ValueError:
        return f"command {cmd}"


def sm_kind(control: int) -> str:
    """What a SyncManager is for, from its control byte (mode bits 1:0, direction 3:2)."""
    writes = control & SM_DIR_MASK == SM_DIR_ECAT_WRITES
    if control & SM_MODE_MASK == SM_MODE_MAILBOX:
        return "mbox out" if writes else "mbox in"
    return "outputs" if writes else "inputs"


def _int(data: bytes) -> int:
    return int.from_bytes(data, "little")


def _hex(data: bytes) -> str:
    return "0x" + data[::-1].hex().upper() if len(data) <= 8 else data.hex()


def _records(ado: int, data: bytes, area: range, size: int) -> list[tuple[int, bytes]] | None:
    """The whole register records (number, bytes) a write of ``data`` at ``ado`` covers in
    ``area``, or None when it does not start on a record or covers part of one."""
    if ado not in area or (ado - area.start) % size or len(data) % size or not data:
        return None
    first = (ado - area.start) // size
    return [(first + k, data[k * size:(k + 1) * size]) for k in range(len(data) // size)]


def _cleared(kind: str, records: list[tuple[int, bytes]]) -> str | None:
    """``clear fmmu 0-15``: a write of zeros to three records or more (the master's
    broadcast clearing of all of them), else None."""
    if len(records) < 3 or any(any(image) for _, image in records):
        return None
    return f"clear {kind} {records[0][0]}-{records[-1][0]}"


def _sm_words(n: int, image: bytes) -> str:
    if not any(image):
        return f"clear sm {n}"
    sm = SmConfig.from_bytes(image)
    text = (f"set sm {n} ({sm_kind(sm.control)}) 0x{sm.start:04X} len {sm.length} "
            f"ctrl 0x{sm.control:02X}")
    return text + ("" if sm.enable else " disabled")


def _fmmu_words(n: int, image: bytes) -> str:
    if not any(image):
        return f"clear fmmu {n}"
    f = FmmuConfig.from_bytes(image)
    kind = {FmmuType.READ: "inputs", FmmuType.WRITE: "outputs",
            FmmuType.READ_WRITE: "inputs+outputs"}.get(f.type, "unused")
    status = f.physical_start - sm_register(0) - 5      # SM n status: 0x0805 + 8n
    if f.physical_start in _SM_AREA and status % SM_SIZE == 0:
        # An FMMU onto a SyncManager's status byte: the mailbox-state bit TwinCAT and
        # EC-Engineer poll in the cyclic frame (SM1 status bit 3, mailbox full).
        kind = f"mailbox state of sm {status // SM_SIZE}"
    end = f.logical_start + f.length - 1
    text = (f"set fmmu {n} ({kind}) logical 0x{f.logical_start:08X}.{f.logical_start_bit}"
            f"-0x{end:08X}.{f.logical_stop_bit} -> 0x{f.physical_start:04X}."
            f"{f.physical_start_bit}")
    return text + ("" if f.active else " inactive")


def _state_words(value: int) -> str:
    """AL control: the state requested, with the error acknowledge and ID request bits."""
    text = f"request {al_state_name(value & ~(AL_ERROR_ACK | AL_ID_REQUEST))}"
    if value & AL_ERROR_ACK:
        text += " +ack"
    if value & AL_ID_REQUEST:
        text += " +id"
    return text


def _register_write(ado: int, data: bytes) -> str | None:
    """Words for a write of a register the configuration sets, or None."""
    sms = _records(ado, data, _SM_AREA, SM_SIZE)
    if sms is not None:
        return _cleared("sm", sms) or "; ".join(_sm_words(n, image) for n, image in sms)
    fmmus = _records(ado, data, _FMMU_AREA, FMMU_SIZE)
    if fmmus is not None:
        return _cleared("fmmu", fmmus) or "; ".join(_fmmu_words(n, image)
                                                    for n, image in fmmus)
    if ado == Reg.AL_CONTROL and data:
        return _state_words(_int(data[:2]))
    if ado == Reg.STATION_ADDRESS and len(data) == 2:
        return f"set station address {_int(data)}"
    if ado == Reg.EEPROM_CONFIG and data:
        return "EEPROM to " + ("PDI" if data[0] & 1 else "ECAT")
    if ado == Reg.EEPROM_CONTROL and len(data) >= 4:
        return f"read SII word 0x{_int(data[2:6]):04X}"
    if ado == Reg.WATCHDOG_DIVIDER and len(data) == 2:
        return f"set watchdog divider {_int(data)} ({watchdog_base_ns(_int(data))} ns)"
    if ado in (Reg.WATCHDOG_PDI, Reg.WATCHDOG_SM) and len(data) == 2:
        # In steps of the divider's time base (0x0400; 100 us at its default 2498): the
        # count alone says nothing a reader can use.
        which = "PDI" if ado == Reg.WATCHDOG_PDI else "SM"
        ms = _int(data) * watchdog_base_ns(WATCHDOG_DIVIDER_DEFAULT) / 1e6
        return f"set {which} watchdog {_int(data)} ({ms:g} ms at the default divider)"
    if ado == Reg.DC_CYCLIC_UNIT_CONTROL and len(data) >= 2:
        return f"set DC activation 0x{_int(data[:2]):04X}" if any(data) else "clear DC activation"
    if ado == Reg.DC_SYNC0_CYCLE_TIME and len(data) in (4, 8):
        text = f"set SYNC0 cycle {_int(data[:4])} ns"
        return text + (f", SYNC1 cycle {_int(data[4:])} ns" if len(data) == 8 else "")
    if ado == Reg.DC_START_TIME_CYCLIC:
        return "set DC start time (the master's)"
    return _named_write(ado, data)


def _named(ado: int, length: int) -> str | None:
    """The registers a command of ``length`` bytes at ``ado`` covers, by name: one
    register (or a byte of one: ``DL control byte 3``) or a list of them."""
    regs = covered(ado, length)
    if not regs:
        return None
    if len(regs) == 1:
        found = containing(ado)
        assert found is not None
        reg, offset = found
        part = f" byte {offset}" if offset or length < reg.size else ""
        return reg.name + part
    return ", ".join(r.name for r in regs)


def _named_write(ado: int, data: bytes) -> str | None:
    """``set ECAT event mask = 0x0004``; zeros over several registers: ``clear ...``."""
    names = _named(ado, len(data))
    if names is None or not data:
        return None
    regs = covered(ado, len(data))
    if len(regs) == 1:
        return f"set {names} = {_value(regs[0].unit, data)}"
    if not any(data):
        return f"clear {names}"
    inside = all(ado <= r.address and r.address + r.size <= ado + len(data) for r in regs)
    if not inside:
        return f"write {names} = {_hex(data)}"
    return "set " + ", ".join(
        f"{r.name} = {_value(r.unit, data[r.address - ado:r.address - ado + r.size])}"
        for r in regs)


def _value(unit: str | None, data: bytes) -> str:
    return f"{_int(data)} ns" if unit == "ns" else _hex(data)


def _register_read(cmd: InitCmd) -> str | None:
    v = cmd.validate
    if v is None:
        names = None if cmd.ado is None else _named(cmd.ado, cmd.length)
        return None if names is None else f"read {names}"
    want = v.data if v.mask is None else bytes(d & m for d, m in zip(v.data, v.mask))
    if cmd.ado == Reg.AL_STATUS and want:
        return f"check state {al_state_name(want[0])}"
    if cmd.ado == Reg.STATION_ALIAS and len(want) == 2:
        return f"check alias {_int(want)}"
    if cmd.ado == Reg.EEPROM_DATA and want:
        return f"check SII data {compared(v.compare)}{_hex(want)}"
    return None


def init_cmd_words(cmd: InitCmd) -> str:
    """A register InitCmd in words (the module docstring lists them)."""
    data = cmd.payload
    words: str | None = None
    if cmd.ado is not None and cmd.cmd in REGISTER_WRITES:
        words = _register_write(cmd.ado, data)
    if words is None and cmd.ado is not None and cmd.cmd in REGISTER_READS:
        words = _register_read(cmd)
    if words is not None:
        return words
    text = command_address(cmd)
    if cmd.cmd in REGISTER_WRITES or cmd.cmd in (Cmd.LWR, Cmd.LRW):
        text += f" = {_hex(data)}"
    else:
        text += f" len {cmd.length}"
    if cmd.validate is not None:
        text += f" expect {compared(cmd.validate.compare)}{_hex(cmd.validate.data)}"
        if cmd.validate.mask is not None:
            text += f" mask {_hex(cmd.validate.mask)}"
    return text


def sdo_value(index: int, subindex: int, data: bytes) -> str:
    """A value written to ``index:subindex``, spelled as the object means it: a PDO index in
    an assignment object, ``0xIIII:SS N bit`` for a mapping entry, a number otherwise."""
    if subindex and index in SM_PDO_ASSIGN_RANGE and len(data) == 2:
        return f"0x{_int(data):04X}"
    if subindex and (index in RX_PDO_MAPPING or index in TX_PDO_MAPPING) and len(data) == 4:
        return mapping_entry(_int(data))
    if len(data) <= 4:
        return str(_int(data))
    return data.hex()


def mapping_entry(value: int) -> str:
    """A PDO mapping entry (ETG.1000.6: index << 16 | subindex << 8 | bit length)."""
    return f"0x{value >> 16:04X}:{value >> 8 & 0xFF:02X} {value & 0xFF} bit"


def _complete_values(index: int, subindex: int, data: bytes) -> str:
    """A CompleteAccess download's data: from subindex 0 the count in a 16-bit slot, then
    the entries (ETG.1000.6 SDO complete access), for the PDO objects; bytes otherwise."""
    size = 2 if index in SM_PDO_ASSIGN_RANGE else \
        4 if index in RX_PDO_MAPPING or index in TX_PDO_MAPPING else 0
    if not size:
        return data.hex()
    head = ""
    if subindex == 0 and data:
        head, data = f"{data[0]}: ", data[2:]
    entries = [_int(data[k:k + size]) for k in range(0, len(data) - size + 1, size)]
    spelled = [f"0x{e:04X}" if size == 2 else mapping_entry(e) for e in entries]
    return head + ", ".join(spelled)


def coe_words(cmd: CoeInitCmd) -> str:
    """``SDO 0x1C12:00 = 0``; an upload is ``SDO upload 0x1018:01``."""
    where = f"0x{cmd.index:04X}:{cmd.subindex:02X}"
    if cmd.ccs != 1:
        return f"SDO upload {where}" if cmd.ccs == 2 else f"SDO ccs {cmd.ccs} {where}"
    if cmd.complete_access:
        text = f"SDO {where} complete = {_complete_values(cmd.index, cmd.subindex, cmd.data)}"
    else:
        text = f"SDO {where} = {sdo_value(cmd.index, cmd.subindex, cmd.data)}"
    return text + (" (disabled)" if cmd.disabled else "")


def eoe_words(cmd: EoeInitCmd) -> str:
    """``EoE set IP ip 192.168.1.4/255.255.255.0, gateway ...``."""
    try:
        return f"EoE set IP {cmd.request.params.describe()}"
    except ValueError:             # the reader has checked it decodes; a hand-made plan
        return f"EoE {cmd.data.hex()}"


def _place(bit: int, variables: list[Variable], direction: str) -> str:
    """``sensors.Channel 1.Input (in 0.4)``, ``axis1.Statusword +3 (in 2.3)``, ``in 7.0``."""
    where = f"{direction} {bit // 8}.{bit % 8}"
    for v in variables:
        if v.bit_offs <= bit < v.bit_offs + v.bit_size:
            inside = f" +{bit - v.bit_offs}" if bit != v.bit_offs else ""
            return f"{v.name}{inside} ({where})"
    return where


def copy_words(copy: CopyInfo, inputs: list[Variable], outputs: list[Variable]) -> str:
    """A copy by the variables at its first source and destination bit (the process
    image's variables, ``ProcessImage/Inputs`` and ``Outputs``)."""
    n = copy.bit_size
    return (f"copy {n} bit{'s' if n != 1 else ''}: "
            f"{_place(copy.src_bit_offs, inputs, 'in')} -> "
            f"{_place(copy.dst_bit_offs, outputs, 'out')}")


def soe_init_cmd_name(cmd: SoeInitCmd) -> str:
    """How messages name an SoE InitCmd (as :func:`init_cmd_name` a register one): its
    comment, else ``SoE write S-0-0001 (drive 0)``."""
    return cmd.comment.strip() or f"SoE write {idn_text(cmd.idn)} (drive {cmd.drive_no})"


def soe_words(cmd: SoeInitCmd) -> str:
    """``SoE write S-0-0001 (drive 0) = d0 07``; another element than the value, or another
    OpCode than a write request, is named (``elements 0x08``, ``SoE OpCode 1``)."""
    service = "SoE write" if cmd.op_code == WRITE_REQUEST else f"SoE OpCode {cmd.op_code}"
    text = f"{service} {idn_text(cmd.idn)} (drive {cmd.drive_no})"
    if cmd.elements != VALUE_ELEMENT:
        text += f" elements 0x{cmd.elements:02X}"
    if cmd.data or cmd.op_code == WRITE_REQUEST:
        text += " = " + (cmd.data.hex(" ") if cmd.data else "(no data)")
    return text + (" (disabled)" if cmd.disabled else "")


def foe_words(cmd: FoeInitCmd) -> str:
    """``FoE read 'config.bin' (password 0x0000002A)``; another OpCode by number (the
    reader has refused it unless it is disabled)."""
    if cmd.opcode == FoeOpCode.READ:
        password = f" (password 0x{cmd.password:08X})" if cmd.password else ""
        text = f"FoE read {cmd.file_name!r}{password}"
    elif cmd.opcode == FoeOpCode.WRITE:
        text = f"FoE write {cmd.file_name!r}"
    else:
        text = f"FoE {cmd.data.hex()}"
    return text + (" (disabled)" if cmd.disabled else "")
