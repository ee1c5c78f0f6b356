"""What a SOEM-based master must be told to do for each slave of an ENI.

SOEM (and pysoem, which wraps it) configures a slave by itself: ``ecx_config_init`` resets
the line, sets station addresses, reads the SII and sets up the mailbox SyncManagers;
``ecx_config_map_group`` reads the PDO assignment over CoE, sizes and writes the process
data SyncManagers and FMMUs and requests SAFEOP; ``ecx_configdc`` and ``ecx_dcsync0/01``
measure the delays and program SYNC0/1 (SOEM ``ethercatconfig.c``, ``ethercatdc.c``).
Between reading the SII and reading the PDO assignment it calls each slave's
``PO2SOconfig`` hook, in PREOP: the place where a user writes the PDO assignment and
mapping and the start-up SDOs.

So of an ENI's InitCmds the export keeps what SOEM's own sequence does not do:

- the CoE downloads of PREOP->SAFEOP (``PS``), and those of INIT->PREOP (``IP``: the
  mailbox works once the slave is in PREOP, as SOEM leaves it after ``config_init``), in
  ENI order, with CompleteAccess where the ENI says;
- register writes and checks outside the registers SOEM configures itself
  (:data:`SOEM_REGISTERS`), of the same transitions, before the CoE downloads;
- the SoE writes of the same transitions (``Mailbox/SoE/InitCmds``), after the CoE
  downloads: SOEM's ``ecx_SoEwrite`` makes them (``ethercatsoe.c``); pysoem has no SoE
  call, so the pysoem export refuses them (:func:`ecatcfg.eni.export.pysoem_module.check`);
- the DC settings of ``Slave/DC`` (SYNC0/1 cycle and shift).

Anything else that would change what the master does and that no hook can carry (a CoE or
non-SOEM register command of another transition, EoE commands, slave-to-slave copies,
parts of the ENI ``apply`` does not implement) is an :class:`ExportError` naming the file,
line and slave: nothing is dropped silently.  Disabled CoE commands are not run by any master and are left out.
"""

from __future__ import annotations

from pathlib import Path

from ecatcfg.eni.plan import (BitRange, CoeInitCmd, DcPlan, EoeInitCmd, InitCmd,
                              NetworkPlan, SlavePlan, SoeInitCmd, Variable)
from ecatcfg.eni.source import copy_info_line, init_cmd_line
from ecatcfg.eni.words import coe_words, copy_words, foe_words, init_cmd_words, soe_words
from ecatcfg.errors import EcatcfgError
from ecatcfg.esc import (DC_ACTIVATION, REGISTER_READS, REGISTER_WRITES,
                         Transition, fmmu_register, sm_register)
from ecatcfg.record import field, record

# Registers SOEM's own configuration writes, reads or resets (SOEM ethercatconfig.c
# ecx_detect_slaves / ecx_config_init / ecx_config_map_group, ethercatdc.c): station address
# and alias 0x0010-0x0013, DL control and port 0x0100-0x0103, AL control and status
# 0x0120-0x0135, PDI control 0x0140 (ESC type, read by the master's checks only), IRQ mask
# 0x0200, error counters 0x0300-0x0313, SII interface 0x0500-0x050F, the FMMUs
# 0x0600-0x06FF, the SyncManagers 0x0800-0x08FF (an ENI clears all 32), DC time, delay,
# filter, activation, start and cycle times 0x0900-0x09A7 (ESC datasheet Section II
# register map).
SOEM_REGISTERS: tuple[range, ...] = (
    range(0x0010, 0x0014), range(0x0100, 0x0104), range(0x0120, 0x0136),
    range(0x0140, 0x0142), range(0x0200, 0x0202), range(0x0300, 0x0314),
    range(0x0500, 0x0510), range(fmmu_register(0), fmmu_register(16)),
    range(sm_register(0), sm_register(32)), range(0x0900, 0x09A8))

# The transitions a PO2SOconfig hook stands for: it runs in PREOP before SAFEOP is requested.
HOOK_TRANSITIONS = frozenset({Transition.IP, Transition.PS})


class ExportError(EcatcfgError):
    """Something in the ENI that the exported code cannot carry out."""


@record
class SdoStep:
    index: int
    subindex: int
    data: bytes
    complete_access: bool
    words: str                                # eni/words.py: ``SDO 0x1C12:00 = 0``


@record
class SoeStep:
    drive_no: int
    elements: int
    idn: int
    data: bytes
    words: str                                # eni/words.py: ``SoE write S-0-0001 ...``
    line: int | None                          # its InitCmd in the ENI file


@record
class RegisterStep:
    ado: int
    data: bytes                               # written, or expected (read)
    write: bool
    mask: bytes | None
    length: int
    words: str


@record
class ImageEntry:
    """A variable of the process image at its place in its slave's own data: the bits of
    the slave's Send (or Recv) ranges, each range from a whole byte (its SyncManager's
    data).  Where a master puts those bytes is the master's layout (SOEM's:
    :mod:`.soem_image`)."""

    name: str
    bit_offs: int                             # within the slave's own bytes
    bit_size: int
    data_type: str | None


@record
class SlaveSetup:
    position: int                             # 0 = first slave
    name: str
    vendor_id: int
    product_code: int
    revision: int
    registers: list[RegisterStep] = field(default_factory=list)
    sdos: list[SdoStep] = field(default_factory=list)
    dc: DcPlan | None = None
    sync_activation: int = 0                  # the ENI's 0x0981 byte: SYNC0 0x02, SYNC1 0x04
    output_bits: int = 0                      # ProcessData Send
    input_bits: int = 0                       # ProcessData Recv
    outputs: list[ImageEntry] = field(default_factory=list)
    inputs: list[ImageEntry] = field(default_factory=list)
    soe: list[SoeStep] = field(default_factory=list)
    send: list[BitRange] = field(default_factory=list)      # the ENI's ProcessData Send
    recv: list[BitRange] = field(default_factory=list)      # and Recv, in its own image


def soem_register(ado: int, length: int) -> bool:
    """Whether SOEM's own configuration covers the registers ``ado``..``ado+length-1``."""
    return any(ado in r and ado + max(length, 1) - 1 in r for r in SOEM_REGISTERS)


def _refuse(file: str, plan: NetworkPlan, slave: SlavePlan,
            cmd: InitCmd | CoeInitCmd | EoeInitCmd | SoeInitCmd, what: str) -> ExportError:
    return ExportError(f"slave {slave.position} ({slave.name!r}): {what}: the exported "
                       f"hooks run in PREOP before SAFEOP only (IP, PS)", file,
                       init_cmd_line(file, plan, cmd))


def _in_hook_only(file: str, plan: NetworkPlan, slave: SlavePlan,
                  cmd: InitCmd | CoeInitCmd | SoeInitCmd, words: str) -> None:
    """Refuse a command that runs in a transition the hook does not stand for, also when
    it runs in IP or PS as well: exported once, its repeat (in SAFEOP->OP, on the way
    down) would be lost without a word."""
    other = [t.value for t in cmd.transitions if t not in HOOK_TRANSITIONS]
    if other:
        raise _refuse(file, plan, slave, cmd, f"{words} in "
                      f"{'/'.join(t.value for t in cmd.transitions)} ({'/'.join(other)} "
                      "too)" if len(other) < len(cmd.transitions) else f"{words} in "
                      f"{'/'.join(other)}")


def _sync_activation(slave: SlavePlan) -> int:
    """The DC activation byte (0x0981, ESC Section II) the slave has when it enters SAFEOP,
    which ``dc_sync`` programs through SOEM instead: the last write of INIT->PREOP, then of
    PREOP->SAFEOP (an ENI clears it in IP and sets it in PS); 0 when they write none."""
    value = 0
    for transition in (Transition.IP, Transition.PS):
        for cmd in slave.init_cmds:
            if cmd.cmd in REGISTER_WRITES and cmd.ado is not None and \
                    transition in cmd.transitions and \
                    cmd.ado <= DC_ACTIVATION < cmd.ado + len(cmd.payload):
                value = cmd.payload[DC_ACTIVATION - cmd.ado]
    return value


def _register_steps(file: str, plan: NetworkPlan, slave: SlavePlan) -> list[RegisterStep]:
    steps = []
    for cmd in slave.init_cmds:
        if cmd.ado is None or soem_register(cmd.ado, cmd.length):
            continue                          # logical, broadcast or SOEM's own: SOEM's
        write = cmd.cmd in REGISTER_WRITES
        if not write and (cmd.cmd not in REGISTER_READS or cmd.validate is None):
            continue                          # a read nobody checks changes nothing
        _in_hook_only(file, plan, slave, cmd, init_cmd_words(cmd))
        if write:
            steps.append(RegisterStep(cmd.ado, cmd.payload, True, None, cmd.length,
                                      init_cmd_words(cmd)))
        else:
            assert cmd.validate is not None
            steps.append(RegisterStep(cmd.ado, cmd.validate.data, False, cmd.validate.mask,
                                      cmd.length, init_cmd_words(cmd)))
    return steps


def _sdo_steps(file: str, plan: NetworkPlan, slave: SlavePlan) -> list[SdoStep]:
    if slave.mailbox is None:
        return []
    for eoe in slave.mailbox.eoe_init_cmds:
        if not eoe.disabled:
            raise ExportError(f"slave {slave.position} ({slave.name!r}): EoE InitCmd "
                              f"({eoe.comment or 'set IP parameter'}): SOEM's hooks carry "
                              f"CoE only", file, init_cmd_line(file, plan, eoe))
    for foe in slave.mailbox.foe_init_cmds:
        if not foe.disabled:
            raise ExportError(f"slave {slave.position} ({slave.name!r}): FoE InitCmd "
                              f"({foe.comment or foe_words(foe)}): SOEM's hooks carry "
                              f"CoE only", file, init_cmd_line(file, plan, foe))
    steps = []
    for ip_first in (True, False):            # IP's downloads before PS's (ETG.2100 order)
        for cmd in slave.mailbox.coe_init_cmds:
            if cmd.disabled:
                continue
            _in_hook_only(file, plan, slave, cmd, coe_words(cmd))
            if (Transition.IP in cmd.transitions) != ip_first:
                continue
            if cmd.ccs != 1:
                raise ExportError(f"slave {slave.position} ({slave.name!r}): "
                                  f"{coe_words(cmd)}: only SDO downloads are exported",
                                  file, init_cmd_line(file, plan, cmd))
            steps.append(SdoStep(cmd.index, cmd.subindex, cmd.data, cmd.complete_access,
                                 coe_words(cmd)))
    return steps


def _soe_steps(file: str, plan: NetworkPlan, slave: SlavePlan) -> list[SoeStep]:
    """The slave's SoE writes, in ENI order: those of PS (an ENI gives SoE no IP)."""
    steps = []
    for cmd in slave.mailbox.soe_init_cmds if slave.mailbox else []:
        if cmd.disabled:
            continue
        _in_hook_only(file, plan, slave, cmd, soe_words(cmd))
        steps.append(SoeStep(cmd.drive_no, cmd.elements, cmd.idn, cmd.data, soe_words(cmd),
                             init_cmd_line(file, plan, cmd)))
    return steps


def _entries(variables: list[Variable], ranges: list[BitRange]) -> list[ImageEntry]:
    """The variables inside ``ranges`` (a slave's Send or Recv), at their bit offset in the
    slave's own bytes: the ranges follow each other there, each from a whole byte."""
    out = []
    for v in sorted(variables, key=lambda v: v.bit_offs):
        base = 0
        for r in ranges:
            if r.bit_start <= v.bit_offs < r.bit_start + r.bit_length:
                out.append(ImageEntry(v.name, base + v.bit_offs - r.bit_start, v.bit_size,
                                      v.data_type))
                break
            base += (r.bit_length + 7) // 8 * 8
    return out


def refuse_unexported(plan: NetworkPlan, name: str, copies: str, master_writes: str) -> None:
    """What no export carries, refused by name before anything is written: a part of the
    ENI the reader kept as unsupported, slave-to-slave copies (``copies``: how the refusal
    words them for the target) and the master's own register writes outside what a
    master sets up itself (``master_writes``: the target's reason).  Each target's own
    limits come after."""
    if plan.unsupported:
        u = plan.unsupported[0]
        who = f"slave {u.slave!r}" if u.slave else "the master"
        raise ExportError(f"{who}: {u.describe()} ({u.element}) is not implemented; "
                          f"{len(plan.unsupported)} such part(s) in all", name, u.line)
    for cyclic in plan.cyclic:
        for frame in cyclic.frames:
            for c in frame.cmds:
                if c.copy_infos:
                    copy = c.copy_infos[0]
                    words = copy_words(copy, plan.process_image.inputs,
                                       plan.process_image.outputs)
                    raise ExportError(f"the master: slave-to-slave copies (CopyInfos) are "
                                      f"{copies}: {words}", name,
                                      copy_info_line(name, plan, copy))
    for cmd in plan.master.init_cmds:
        if cmd.ado is not None and not soem_register(cmd.ado, cmd.length) and \
                cmd.cmd in REGISTER_WRITES:
            raise ExportError(f"the master: InitCmd {init_cmd_words(cmd)}: {master_writes}",
                              name)


def slave_setups(plan: NetworkPlan, file: str | Path) -> list[SlaveSetup]:
    """Each slave's set-up for a SOEM hook, from the plan read from ``file``; raises
    :class:`ExportError` for what no hook can carry."""
    name = str(file)
    # Copies: SOEM's cycle (send/receive_processdata over its own IOmap) has no place for
    # them, and its working counter is the group's, not the command's: the export would
    # copy data the ENI calls invalid.
    refuse_unexported(plan, name, "not exported", "SOEM's hooks are per slave")
    out = []
    for slave in plan.slaves:
        pd = slave.process_data
        send = pd.send if pd else []
        recv = pd.recv if pd else []
        out.append(SlaveSetup(
            slave.position, slave.name, slave.vendor_id, slave.product_code, slave.revision,
            _register_steps(name, plan, slave), _sdo_steps(name, plan, slave), slave.dc,
            _sync_activation(slave),
            sum(r.bit_length for r in send), sum(r.bit_length for r in recv),
            _entries(plan.process_image.outputs, send),
            _entries(plan.process_image.inputs, recv), _soe_steps(name, plan, slave),
            list(send), list(recv)))
    return out
