"""One emulated EtherCAT slave: an ESC's registers and memory plus the firmware behind them.

Built from the device's ESI: the SII EEPROM image (``esi/sii.py``) backs the SII interface
(0x0500-0x050F) and loads the configured alias and PDI control at power-on; the object
dictionary (``runtime/segment/objects.py``) backs the CoE SDO server and decides which
SyncManager lengths the slave accepts in SAFEOP; the mailbox
(``runtime/segment/mailbox_server.py``) hands each message the master writes to the protocol's
server (CoE, EoE, SoE, FoE; in BOOT FoE alone).  Register addresses and the rules the firmware applies are those of
``docs/protocol-notes.md`` §2-§4 (ETG.1000.4/.6, SOES, KickCAT).

The ESC's 64 KiB address space is one ``bytearray``: registers below 0x1000, process memory
above.  Reads and writes from the wire go through :meth:`EmulatedSlave.read` and
:meth:`EmulatedSlave.write`, which refuse what a real ESC refuses (no working counter) and
run the side effects of the registers written.  The segment (``runtime/segment/virtual.py``) does
the addressing and logical (FMMU) accesses.
"""

from __future__ import annotations

import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ecatcfg.esc import (AL_ERROR_ACK, AL_ID_REQUEST, AL_STATE_MASK, AL_STATUS_ERROR,
                         AL_STATUS_ID, EEPROM_BUSY,
                         EEPROM_CMD_MASK, EEPROM_CMD_READ, EEPROM_CMD_RELOAD, EEPROM_CMD_WRITE,
                         EEPROM_ERROR_ACKNOWLEDGE, EEPROM_ERROR_WRITE_ENABLE, EEPROM_R64,
                         EEPROM_WRITE_ENABLE, ESC_DEVICE_EMULATION, FMMU_SIZE, PDI_DIGITAL_IO,
                         SII_BOOTSTRAP_MAILBOX, SII_REVISION, SM_ACTIVATE_REPEAT,
                         SM_INPUT_PARAMETER, SM_OUTPUT_PARAMETER, SM_PARAMETER_MIN_CYCLE,
                         SM_WATCHDOG_ENABLE, AlState, AlStatusCode, FmmuConfig, FmmuType,
                         Reg, fmmu_register,
                         sm_register)
from ecatcfg.esc import WATCHDOG_DIVIDER_DEFAULT, WATCHDOG_TIME_DEFAULT, watchdog_base_ns
from ecatcfg.esi.model import Device
from ecatcfg.runtime.refusals import Refusal, Rule
from ecatcfg.runtime.segment import al_checks
from ecatcfg.runtime.segment.dc_clock import (SPEED_COUNTER_START, SPEED_FILTER_DEPTH,
                                              TIME_FILTER_DEPTH, DcClock)
from ecatcfg.runtime.segment.esc_chips import GENERIC, EscChip
from ecatcfg.runtime.segment.syncman import SmKind, SmState

if TYPE_CHECKING:                   # only slaves with a mailbox bring these
    from ecatcfg.eoe import IpParameters
    from ecatcfg.runtime.segment.mailbox_server import MailboxServer
    from ecatcfg.runtime.segment.objects import ObjectDictionary
    from ecatcfg.runtime.segment.timing import SlaveTiming

MEMORY_SIZE = 0x10000
PROCESS_RAM = 0x1000
N_FMMU = 8
N_SM = 8

DEFAULT_WD_DIVIDER = WATCHDOG_DIVIDER_DEFAULT     # (0x09C2 + 2) x 40 ns = 100 us time base
DEFAULT_WD_TIME = WATCHDOG_TIME_DEFAULT           # x 100 us = 100 ms

# Transitions the state machine allows (SOES ESC_state, KickCAT ESMStates); any -> INIT too.
# BOOT is entered from INIT only and left to INIT only (ETG.1000.6 state machine).
_ALLOWED = {(AlState.INIT, AlState.PREOP), (AlState.INIT, AlState.BOOT),
            (AlState.PREOP, AlState.SAFEOP),
            (AlState.SAFEOP, AlState.OP), (AlState.OP, AlState.SAFEOP),
            (AlState.OP, AlState.PREOP), (AlState.SAFEOP, AlState.PREOP)}
_LETTER = {AlState.INIT: "I", AlState.PREOP: "P", AlState.BOOT: "B", AlState.SAFEOP: "S",
           AlState.OP: "O"}
_STATES: dict[int, AlState] = {int(s): s for s in AlState}
# The states in which process data moves (ETG.1000.6: inputs from SAFEOP, outputs in OP).
RUNNING_STATES = (int(AlState.SAFEOP), int(AlState.OP))

# ECAT event request 0x0210 bit 2: DL status changed, cleared when the master reads 0x0110
# (ESC Section II, 0x0210).
DL_STATUS_EVENT = 0x0004
# Registers the master cannot write (device information, status, EEPROM-loaded values).
_READ_ONLY = [(0x0000, 0x0010), (0x0110, 0x0112), (0x0130, 0x0136), (0x0140, 0x0142),
              (0x0150, 0x0154), (0x0210, 0x0214), (0x0440, 0x0444), (0x0982, 0x0985)]
# DC: system time difference and speed counter diff (ESC Section II 0x092C, 0x0932).
_READ_ONLY += [(0x092C, 0x0930), (0x0932, 0x0934)]
_READ_ONLY += [(sm_register(n) + 5, sm_register(n) + 6) for n in range(N_SM)]
_READ_ONLY += [(sm_register(n) + 7, sm_register(n) + 8) for n in range(N_SM)]


@dataclass(frozen=True, slots=True)
class StateChange:
    """What the segment reports: a slave that moved, or refused to."""

    position: int
    name: str
    state: AlState
    error: bool
    code: int
    note: str = ""          # e.g. a device-emulation slave running with other SM lengths


# DC registers whose writes the ESC acts on: system time (0x0910) to the SYNC0 start time.
_DC_LOOP, _DC_LOOP_END = 0x0910, 0x0998


def _overlaps(a: int, n: int, start: int, end: int) -> bool:
    return a < end and a + n > start


# Register blocks an ESC without the resource does not implement: FMMUs and SMs past its
# count (the address map has room for 16 of each), the DC system-time unit.  An access that
# lies wholly inside one gets no working counter, as a real ET1100 (8 of each) answers a BWR
# to FMMU 8-15 or SM 8-15 and an ET1200 (3 FMMUs, 4 SMs) one to FMMU 3-7 or SM 4-7
# (ethercrab-rs/ethercrab tests/replay-ek1100-el2828-el2889.pcapng; runtime/segment/esc_chips.py).
_DC_UNIT = (Reg.DC_SYSTEM_TIME, 0x0A00)


def _absent_blocks(chip: EscChip) -> tuple[tuple[int, int], ...]:
    blocks = [(fmmu_register(chip.fmmus), fmmu_register(16)),
              (sm_register(chip.sms), sm_register(16))]
    if not chip.dc_unit:
        blocks.append(_DC_UNIT)
    return tuple(blocks)


# Read-only registers whose write gets no working counter: a BWR of 0x092C (system time
# difference) comes back with 0 from an EK1100, EL2828 and EL2889 while their other DC
# registers count (ethercrab-rs/ethercrab tests/replay-dc.pcapng).
_UNWRITABLE = ((Reg.DC_SYSTEM_TIME_DIFFERENCE, Reg.DC_SYSTEM_TIME_DIFFERENCE + 4),)
# The error counters (ESC Section II 0x0300-0x0313; Section I "Errors and forwarded
# errors"): per port n an invalid frame counter (0x0300 + 2n) and a physical-layer RX error
# counter (0x0301 + 2n), forwarded RX error counters 0x0308 + n, the ECAT processing unit
# error counter 0x030C, lost link counters 0x0310 + n.  Each stops at 0xFF; a write to
# any of 0x0300-0x030C clears those, a write to any of 0x0310-0x0313 clears the lost link
# counters.
_RX_ERRORS_END = 0x030D
_FORWARDED = 0x0308
_LOST_LINK = 0x0310
_LOST_LINK_END = 0x0314


# The registers whose write the ESC acts on (EmulatedSlave._after_register_write): AL
# control, the watchdogs, the EEPROM interface, FMMUs, SMs, the DC unit.  A write that
# meets none of them only stores its bytes.
_ACTED_ON = ((Reg.AL_CONTROL, Reg.AL_CONTROL + 2), (Reg.WATCHDOG_DIVIDER, Reg.WATCHDOG_SM + 2),
             (Reg.WATCHDOG_COUNTER_SM, Reg.WATCHDOG_COUNTER_SM + 2), (0x0502, 0x0508),
             (Reg.FMMU0, Reg.FMMU0 + FMMU_SIZE * N_FMMU), (Reg.SM0, sm_register(N_SM)),
             (_DC_LOOP, _DC_LOOP_END), (Reg.RX_ERROR_COUNTER, _LOST_LINK_END))


def _unwritable(ado: int, n: int) -> bool:
    return any(start <= ado and ado + n <= end for start, end in _UNWRITABLE)


class EmulatedSlave:
    """An ESC and its firmware, emulated from the device's ESI."""

    def __init__(self, device: Device, sii_image: bytes, *, name: str = "",
                 od: ObjectDictionary | None = None,
                 mailbox: MailboxServer | None = None, chip: EscChip = GENERIC,
                 device_id: int | None = None) -> None:
        self.device = device
        self._device_id: int | None = None
        self._id_ado = device.info.identification_ado if device.info else None
        self._id_shown = False              # AL status bit 5: 0x0134 holds the ID
        self._al_code = 0                   # the AL status code while the ID is shown
        self.chip = chip
        self._absent_blocks = _absent_blocks(chip)
        self.name = name or device.type_name
        # Why the device comes from the ENI alone (runtime/segment/eni_device.py), else None.
        self.eni_only: str | None = None
        # The time every behaviour of this slave reads (ns, monotonic): the segment's clock
        # (VirtualSegment(clock_ns=...)), wall time unless a test simulates time.
        self.clock_ns: Callable[[], int] = time.monotonic_ns
        # How long the firmware and the EEPROM take (runtime/segment/timing.py); None: no time.
        self.timing: SlaveTiming | None = None
        # Work in progress under the timing model, each with the clock_ns it is done at:
        # an EEPROM read, a state change, mailbox replies (settle() makes them visible).
        self._eeprom_due: int | None = None
        self._eeprom_writing_until = 0         # the EEPROM's write cycle ends (clock_ns)
        self._eeprom_regs = b""
        self._transition: tuple[int, AlState] | None = None
        self._replies: deque[tuple[int, list[bytes]]] = deque()
        self._reply_starts: deque[int] = deque()     # when the firmware starts writing one
        self.eeprom = bytearray(sii_image)
        self.od = od
        # Input values the user holds (simulate --input, its control channel): (index,
        # subindex) -> (bit length, value), put where the current mapping places them.
        self.held_inputs: dict[tuple[int, int], tuple[int, int]] = {}
        # What the dictionary holds at power-on (power_cycle restores it).
        self._od_power_on = {} if od is None else {
            (obj.index, entry.subindex): entry.value for obj in od for entry in
            obj.entries.values()}
        self.mailbox = mailbox
        self.mem = bytearray(MEMORY_SIZE)
        self.position = 0
        self.sms = [SmState(n) for n in range(N_SM)]
        self.fmmus: list[FmmuConfig] = []
        self.mailbox_queue: deque[bytes] = deque()
        self.last_mailbox: bytes | None = None
        self.refuse: dict[str, int] = {}       # fault injection: transition ("PS") -> code
        # The last state change the firmware refused, with the rule it applied
        # (runtime/refusals.py); None until one is refused.
        self.refusal: Refusal | None = None
        self.on_state_change: Callable[[StateChange], None] | None = None
        self.on_mapping_change: Callable[[], None] | None = None
        self.outputs_valid = False
        self._last_output_write = 0.0
        self._watchdog_limit: float | None = None
        self._watchdog_expired = False
        # The ESC's local clock and time control loop; the segment gives each slave its
        # drift and place on the line (runtime/segment/dc_clock.py).
        self.dc = DcClock()
        # SYNC0 start time (0x0990) minus the system time when it was written (ns).
        self.sync0_start_lead_ns: int | None = None
        self._ro = bytearray(PROCESS_RAM)
        for start, end in _READ_ONLY:
            self._ro[start:end] = b"\x01" * (end - start)
        self._expected_pd = al_checks.default_pd_bits(self.device)
        self._internal_sms = al_checks.internally_mapped_sms(self.device, self._expected_pd)
        # The firmware's own mailbox: the SMs the ESI names MBoxOut/MBoxIn (SOES keeps
        # them in its configuration, ESCvar.mb[0..1], and writes replies to its own SM1).
        self._mbx_in = next((sm.number for sm in device.sms if sm.type == "MBoxIn"), None)
        self._power_on()
        self.device_id = device_id

    @property
    def device_id(self) -> int | None:
        """The explicit device ID (ETG.1020 "Requesting ID"): the value of an ID switch,
        which the firmware shows in AL status code 0x0134 when the master asks (AL control
        bit 5); ``None``: the device has none and ignores the request.  Set it like
        turning the switch: the next request shows the new value.  A device-emulation ESC
        (no firmware) only mirrors bit 5 and leaves 0x0134 alone (``_mirror_al_control``).
        A device whose ESI names an ``Info/IdentificationAdo`` (the EK1101's ID switch at
        0x1000, read through its digital-input PDI) shows the value there, 16 bits, all the
        time."""
        return self._device_id

    @device_id.setter
    def device_id(self, value: int | None) -> None:
        if value is not None and not 0 <= value <= 0xFFFF:
            raise ValueError(f"a device ID is 16 bits (AL status code 0x0134), not {value}")
        self._device_id = value
        ado = self._id_ado
        if ado is not None and 0 <= ado <= MEMORY_SIZE - 2:
            struct.pack_into("<H", self.mem, ado, value or 0)

    # -- power-on ---------------------------------------------------------------------------

    def power_cycle(self) -> None:
        """Switch the slave off and on: every register and the firmware start afresh (INIT,
        no SyncManagers, FMMUs or addresses: station address 0x0010 reads 0), the EEPROM
        keeps what was written, and what an ESC loads from it at power-on (PDI control,
        the station alias 0x0012) is loaded again.  The local clock restarts from 0 with
        its time control loop reset (0x0910-0x0935 are registers: ESC Section I 9.1, the
        local time counts from power-on); its quartz keeps its drift.  The segment's clock,
        timing, callbacks and the slave's place (position, port times) stay."""
        keep = (self.clock_ns, self.timing, self.on_state_change, self.on_mapping_change,
                self.position, self.eni_only, self.refuse, self.held_inputs)
        drift, ports = self.dc.drift, self.dc.ports
        # The firmware starts afresh too: the object dictionary holds its power-on values
        # again (what the master downloaded, a PDO assignment or mapping, is gone until it
        # downloads it again), the mailbox forgets what was in progress, EoE its IP
        # parameters and SoE drives the IDNs written.
        if self.od is not None:
            for (index, sub), value in self._od_power_on.items():
                self.od[index][sub].value = value
        if self.mailbox is not None:
            self.mailbox.reset()
            if self.mailbox.eoe is not None:
                self.mailbox.eoe.params = None
            if self.mailbox.soe is not None:
                self.mailbox.soe.power_on()
            if self.mailbox.foe is not None:
                self._install_firmware(self.mailbox.foe.take_pending_revision())
        self.__init__(self.device, bytes(self.eeprom),   # type: ignore[misc]
                      name=self.name, od=self.od, mailbox=self.mailbox, chip=self.chip,
                      device_id=self.device_id)
        # A held input is a button still pressed: the power cycle does not release it.
        (self.clock_ns, self.timing, self.on_state_change, self.on_mapping_change,
         self.position, self.eni_only, self.refuse, self.held_inputs) = keep
        self.dc = DcClock(drift, 0, self.clock_ns(), ports)

    def _install_firmware(self, revision: int | None) -> None:
        """A firmware written over FoE starts at power-on and reports its revision: in the
        SII revision word (0x0C; outside the CRC of words 0-6) and in 0x1018:03."""
        if revision is None:
            return
        struct.pack_into("<I", self.eeprom, 2 * SII_REVISION, revision)
        if self.od is not None and 0x1018 in self.od and 3 in self.od[0x1018].entries:
            value = struct.pack("<I", revision)
            self._od_power_on[(0x1018, 3)] = value
            self.od[0x1018][3].value = value

    def _power_on(self) -> None:
        m = self.mem
        chip = self.chip
        m[0x0000] = chip.type
        m[0x0001] = chip.revision
        struct.pack_into("<H", m, 0x0002, chip.build)
        m[0x0004] = chip.fmmus
        m[0x0005] = chip.sms
        m[0x0006] = chip.ram_kb
        m[Reg.PORT_DESCRIPTOR] = self._port_descriptor()
        struct.pack_into("<H", m, 0x0008, chip.features)
        # DL control byte 2 after reset: RX FIFO size 7 and bits 22-23 set, as an EK1100
        # (ET1100) and an EL1004 (ET1200) read it (ethercrab-rs/ethercrab
        # dumps/twincat-scan-boxes.pcapng).
        m[Reg.DL_CONTROL_2 - 1] = 0xC7
        struct.pack_into("<H", m, Reg.AL_STATUS, AlState.INIT)
        struct.pack_into("<H", m, Reg.WATCHDOG_DIVIDER, DEFAULT_WD_DIVIDER)
        struct.pack_into("<H", m, Reg.WATCHDOG_PDI, DEFAULT_WD_TIME)
        struct.pack_into("<H", m, Reg.WATCHDOG_SM, DEFAULT_WD_TIME)
        m[Reg.WATCHDOG_STATUS] = 1                  # SM watchdog status: OK
        struct.pack_into("<H", m, Reg.EEPROM_CONTROL, EEPROM_R64)
        struct.pack_into("<H", m, Reg.DC_SPEED_COUNTER_START, SPEED_COUNTER_START)
        m[Reg.DC_TIME_FILTER] = TIME_FILTER_DEPTH
        m[Reg.DC_TIME_FILTER + 1] = SPEED_FILTER_DEPTH
        self._load_eeprom()

    def _port_descriptor(self) -> int:
        """0x0007: two bits per port from the ESI's Physics ("YY" = MII, "KK" = E-Bus)."""
        physics = (self.device.physics or "YY")[:4]
        value = 0
        for port, char in enumerate(physics):
            value |= {"Y": 3, "H": 3, "K": 2, "E": 2}.get(char.upper(), 0) << 2 * port
        return value

    def _load_eeprom(self) -> None:
        """What an ESC copies from the SII config area (words 0-4) after reset or reload."""
        words = struct.unpack_from("<5H", self.eeprom, 0) if len(self.eeprom) >= 10 \
            else (0,) * 5
        struct.pack_into("<H", self.mem, 0x0140, words[0])
        struct.pack_into("<H", self.mem, 0x0150, words[1])
        struct.pack_into("<H", self.mem, 0x0982, words[2])
        struct.pack_into("<H", self.mem, 0x0152, words[3])
        struct.pack_into("<H", self.mem, Reg.STATION_ALIAS, words[4])
        self.mem[0x0110] |= 0x01                    # DL status: EEPROM loaded

    def set_ports(self, links: tuple[bool, bool, bool, bool]) -> None:
        """DL status 0x0110 from which ports have a link partner: per port n, link (bit
        4+n), and loop open with communication (bits 8+2n = 0, 9+2n = 1; SOEM reads a
        port as active when (status >> 8+2n) & 3 == 2), or loop closed (bit 8+2n = 1)
        without one.  Bit 1, the PDI watchdog, reads 1 (reloaded) only where a PDI
        reloads it: an ESC whose PDI is off (0x0140 = 0, an EK1100) reads 0x5A31 where an
        EL2828 reads 0x5A33 (ethercrab-rs/ethercrab tests/replay-dc.pcapng)."""
        status = 0x01 | (0x02 if self.mem[Reg.PDI_CONTROL] else 0)
        had = struct.unpack_from("<H", self.mem, Reg.DL_STATUS)[0]
        for port, link in enumerate(links):
            if had & 0x0010 << port and not link:
                self._count(_LOST_LINK + port)      # a link that was up went down
            status |= (0x0010 << port | 0x0200 << 2 * port) if link else 0x0100 << 2 * port
        if status != struct.unpack_from("<H", self.mem, Reg.DL_STATUS)[0]:
            # A change of DL status (the links coming up at power-on) raises the ECAT
            # event; real slaves show it in the IRQ field once the master unmasks it
            # (SOEM and TwinCAT write 0x0200 = 0x0004; ethercrab-rs/ethercrab
            # dumps/soem-sdinfo-ek1100-el1004.pcapng, dumps/twincat-scan-boxes.pcapng).
            self.mem[Reg.ECAT_EVENT_REQUEST] |= DL_STATUS_EVENT
        struct.pack_into("<H", self.mem, Reg.DL_STATUS, status)

    def _count(self, address: int) -> None:
        if self.mem[address] < 0xFF:
            self.mem[address] += 1

    def frame_error(self, port: int, forwarded: bool) -> None:
        """A frame with an error was received on ``port``: the first ESC to see it counts
        it as invalid (0x0300 + 2n) and marks it, each one after counts a forwarded error
        (0x0308 + n) instead (ESC Section I, "Errors and forwarded errors")."""
        self._count(_FORWARDED + port if forwarded else Reg.RX_ERROR_COUNTER + 2 * port)

    # -- state ------------------------------------------------------------------------------

    @property
    def eoe_ip(self) -> IpParameters | None:
        """The IP parameters the master has set over EoE; ``None`` before any (or without
        EoE)."""
        eoe = self.mailbox.eoe if self.mailbox is not None else None
        return eoe.params if eoe is not None else None

    @property
    def device_emulation(self) -> bool:
        """0x0141 bit 0 (from SII word 0): no firmware, the ESC mirrors AL control into AL
        status itself."""
        return bool(self.mem[Reg.ESC_CONFIG] & ESC_DEVICE_EMULATION)

    @property
    def al_status(self) -> int:
        """AL status 0x0130 as the master reads it."""
        status: int = struct.unpack_from("<H", self.mem, Reg.AL_STATUS)[0]
        return status

    @property
    def state(self) -> AlState | None:
        """The state in AL status; ``None`` for a value that is no state, which only a
        device-emulation ESC shows (it mirrors whatever the master wrote)."""
        return _STATES.get(self.mem[Reg.AL_STATUS] & AL_STATE_MASK)

    @property
    def error(self) -> bool:
        return bool(self.mem[Reg.AL_STATUS] & AL_STATUS_ERROR)

    @property
    def status_code(self) -> int:
        code: int = struct.unpack_from("<H", self.mem, Reg.AL_STATUS_CODE)[0]
        return code

    @property
    def station_address(self) -> int:
        address: int = struct.unpack_from("<H", self.mem, Reg.STATION_ADDRESS)[0]
        return address

    @property
    def alias(self) -> int:
        alias: int = struct.unpack_from("<H", self.mem, Reg.STATION_ALIAS)[0]
        return alias

    @property
    def alias_enabled(self) -> bool:
        return bool(self.mem[Reg.DL_CONTROL_2] & 0x01)

    # -- register access from the wire -------------------------------------------------------

    def _absent(self, ado: int, n: int) -> bool:
        """An access wholly inside a register block this ESC does not have."""
        return any(start <= ado and ado + n <= end for start, end in self._absent_blocks)

    def read(self, ado: int, n: int) -> bytes | None:
        """``n`` bytes at ``ado`` as the ESC returns them, or ``None`` when it refuses
        (an empty mailbox, for example): the datagram then gets no working counter."""
        end = ado + n
        if end > MEMORY_SIZE or self._absent(ado, n):
            return None
        if ado < PROCESS_RAM:
            if _overlaps(ado, n, Reg.DL_STATUS, Reg.DL_STATUS + 2):
                self.mem[Reg.ECAT_EVENT_REQUEST] &= ~DL_STATUS_EVENT & 0xFF
            if _overlaps(ado, n, Reg.DC_SYSTEM_TIME, Reg.DC_SYSTEM_TIME + 8):
                struct.pack_into("<Q", self.mem, Reg.DC_SYSTEM_TIME, self._ecat_system_time())
            return bytes(self.mem[ado:end])
        for sm in self.sms:
            if sm.covers(ado, n) and sm.is_mailbox:
                return self._read_mailbox(sm, ado, n)
        return bytes(self.mem[ado:end])

    def write(self, ado: int, data: bytes | memoryview) -> bool:
        """Write from the wire; ``False`` when the ESC refuses (a full mailbox)."""
        n = len(data)
        end = ado + n
        if end > MEMORY_SIZE or self._absent(ado, n) or _unwritable(ado, n):
            return False
        if ado >= PROCESS_RAM:
            for sm in self.sms:
                if sm.covers(ado, n):
                    return self._write_sm_area(sm, ado, data)
            self.mem[ado:end] = data
            return True
        ro = self._ro[ado:min(end, PROCESS_RAM)]
        if any(ro):
            for i, byte in enumerate(data):
                if ado + i >= PROCESS_RAM or not ro[i]:
                    self.mem[ado + i] = byte
        else:
            self.mem[ado:end] = data
        self._after_register_write(ado, n)
        return True

    def registers_mapped_written(self, ado: int, before: bytes) -> None:
        """A logical datagram wrote ``len(before)`` register bytes from ``ado`` through an
        FMMU (``before``: what they held).  An FMMU only turns a logical address into a
        physical one (ESC datasheet Section I, "FMMU"); the access is then the physical
        one, under the same ECAT access rights (Section II, register overview: AL status
        0x0130 and the other status registers are read-only for ECAT).  So read-only
        bytes keep their value and the writes act as a physical write does (AL control
        starts a transition, an FMMU or SM register loads)."""
        n = len(before)
        for i in range(n):
            if self._ro[ado + i] or _unwritable(ado + i, 1):
                self.mem[ado + i] = before[i]
        self._after_register_write(ado, n)

    def mapped_write_is_plain(self, ado: int, end: int) -> bool:
        """Whether register bytes ``ado``..``end`` written through an FMMU need nothing
        but the bytes moved: none read-only, none the ESC acts on (the EL2008's output
        pins at 0x0F00 are such bytes, written every cycle)."""
        return not any(self._ro[ado:end]) and not any(
            _overlaps(ado, end - ado, start, stop) for start, stop in _ACTED_ON + _UNWRITABLE)

    def _after_register_write(self, ado: int, n: int) -> None:
        if not any(_overlaps(ado, n, start, end) for start, end in _ACTED_ON):
            return
        if self._eeprom_due is not None and _overlaps(ado, n, 0x0502, 0x0508):
            # Busy: the ESC ignores writes to the EEPROM interface until the read is done.
            self.mem[0x0502:0x0508] = self._eeprom_regs
        elif _overlaps(ado, n, 0x0502, 0x0504):
            self._eeprom_command()
        if _overlaps(ado, n, Reg.WATCHDOG_COUNTER_SM, Reg.WATCHDOG_COUNTER_SM + 2):
            # Writing either watchdog counter clears both (ESC Section II, 0x0442-0x0443).
            self.mem[Reg.WATCHDOG_COUNTER_SM:Reg.WATCHDOG_COUNTER_SM + 2] = b"\x00\x00"
        if _overlaps(ado, n, Reg.RX_ERROR_COUNTER, _RX_ERRORS_END):
            self.mem[Reg.RX_ERROR_COUNTER:_RX_ERRORS_END] = bytes(
                _RX_ERRORS_END - Reg.RX_ERROR_COUNTER)
        if _overlaps(ado, n, _LOST_LINK, _LOST_LINK_END):
            self.mem[_LOST_LINK:_LOST_LINK_END] = bytes(_LOST_LINK_END - _LOST_LINK)
        if _overlaps(ado, n, Reg.FMMU0, Reg.FMMU0 + FMMU_SIZE * N_FMMU):
            self._load_fmmus()
        if _overlaps(ado, n, Reg.SM0, sm_register(N_SM)):
            for sm in self.sms:
                reg = sm_register(sm.number)
                if _overlaps(ado, n, reg, reg + 8):
                    self._sm_registers_written(sm, ado, n)
        if _overlaps(ado, n, Reg.DC_RECEIVE_TIME_PORT0, Reg.DC_RECEIVE_TIME_PORT0 + 4):
            pass    # receive-time latch: done by the segment, which knows the line
        if _overlaps(ado, n, _DC_LOOP, _DC_LOOP_END):
            self._dc_registers_written(ado, n)
        if (self.mem[Reg.AL_STATUS] & AL_STATE_MASK == AlState.OP
                and (_overlaps(ado, n, Reg.WATCHDOG_DIVIDER, Reg.WATCHDOG_SM + 2)
                     or _overlaps(ado, n, Reg.SM0, sm_register(N_SM)))):
            self._arm_watchdog()
        if _overlaps(ado, n, Reg.AL_CONTROL, Reg.AL_CONTROL + 2):
            self._al_control()

    # -- SII EEPROM interface (0x0500-0x050F) -----------------------------------------------

    def _eeprom_command(self) -> None:
        control = struct.unpack_from("<H", self.mem, Reg.EEPROM_CONTROL)[0]
        command = control & EEPROM_CMD_MASK
        address = struct.unpack_from("<I", self.mem, Reg.EEPROM_ADDRESS)[0]
        if command and self.clock_ns() < self._eeprom_writing_until:
            # The EEPROM is still writing the last word: it does not acknowledge, the ESC
            # reports it and does nothing (ESC Section II 0x0502 bit 13; timing model).
            struct.pack_into("<H", self.mem, Reg.EEPROM_CONTROL,
                             EEPROM_ERROR_ACKNOWLEDGE | EEPROM_R64)
            return
        if command == EEPROM_CMD_READ and self.timing and self.timing.eeprom_read_ns:
            # Busy with the command bits set until the read is done: a real EK1100 reads
            # 0x8140, then 0x0040 (ethercrab-rs/ethercrab tests/replay-ek1100-el2828-el2889
            # .pcapng); the data registers fill at the end.
            struct.pack_into("<H", self.mem, Reg.EEPROM_CONTROL,
                             EEPROM_BUSY | EEPROM_CMD_READ | EEPROM_R64)
            self._eeprom_regs = bytes(self.mem[0x0502:0x0508])
            self._eeprom_due = self.clock_ns() + self.timing.eeprom_read_ns
            return
        if command == EEPROM_CMD_READ:                        # read 4 words
            self._eeprom_read(address)
        elif command == EEPROM_CMD_WRITE and not control & EEPROM_WRITE_ENABLE:
            # Write enable must come in the same access as the command (ESC Section II
            # 0x0502 bits 0 and 14): the word is not written and the error bit says why.
            struct.pack_into("<H", self.mem, Reg.EEPROM_CONTROL,
                             EEPROM_ERROR_WRITE_ENABLE | EEPROM_R64)
            return
        elif command == EEPROM_CMD_WRITE:                     # one word
            if 2 * address + 2 <= len(self.eeprom):
                self.eeprom[2 * address:2 * address + 2] = self.mem[Reg.EEPROM_DATA:
                                                                   Reg.EEPROM_DATA + 2]
            if self.timing and self.timing.eeprom_write_ns:
                self._eeprom_writing_until = self.clock_ns() + self.timing.eeprom_write_ns
        elif command in (EEPROM_CMD_RELOAD, EEPROM_CMD_READ | EEPROM_CMD_WRITE):  # SOEM: 0x0300
            self._load_eeprom()
        # Commands complete at once: busy, command and write-enable bits read back clear.
        struct.pack_into("<H", self.mem, Reg.EEPROM_CONTROL, EEPROM_R64)

    def _eeprom_read(self, address: int) -> None:
        data = bytes(self.eeprom[2 * address:2 * address + 8])
        self.mem[Reg.EEPROM_DATA:Reg.EEPROM_DATA + 8] = data + b"\xff" * (8 - len(data))

    # -- work that takes time (runtime/segment/timing.py) ------------------------------------

    @property
    def busy(self) -> bool:
        """Work in progress that becomes visible later (timing model)."""
        return self._eeprom_due is not None or self._transition is not None \
            or bool(self._replies) or bool(self._reply_starts)

    def settle(self) -> None:
        """Make visible what is done by now (clock_ns): the segment calls this before
        every frame and on its ticks, so a reader never sees work before its time."""
        now = self.clock_ns()
        if self._eeprom_due is not None and now >= self._eeprom_due:
            self._eeprom_due = None
            address, = struct.unpack_from("<I", self.mem, Reg.EEPROM_ADDRESS)
            self._eeprom_read(address)
            struct.pack_into("<H", self.mem, Reg.EEPROM_CONTROL, EEPROM_R64)
        if self._transition is not None and now >= self._transition[0]:
            target = self._transition[1]
            self._transition = None
            self._enter(target)
        while self._reply_starts and now >= self._reply_starts[0]:
            self._reply_starts.popleft()
            sm = self._mailbox_in_sm()
            if sm is not None and not sm.full and sm.read_event:
                # The firmware writes the first byte of its reply into SM1: that clears
                # the read event of the master's last read (ESC datasheet, SM status
                # 0x0805 bit 1); the reply shows when its last byte is written.
                sm.read_event = False
                sm.store_status(self.mem)
        while self._replies and now >= self._replies[0][0]:
            self.mailbox_queue.extend(self._replies.popleft()[1])
            self._post_next()

    # -- FMMUs and SyncManagers --------------------------------------------------------------

    def _load_fmmus(self) -> None:
        fmmus = []
        for n in range(N_FMMU):
            reg = fmmu_register(n)
            cfg = FmmuConfig.from_bytes(self.mem[reg:reg + FMMU_SIZE])
            if cfg.active and cfg.type != FmmuType.UNUSED and cfg.length:
                fmmus.append(cfg)
        self.fmmus = fmmus
        if self.on_mapping_change:
            self.on_mapping_change()

    def _sm_registers_written(self, sm: SmState, ado: int, n: int) -> None:
        reg = sm_register(sm.number)
        was_repeat = sm.repeat_request
        sm.load(self.mem)
        request = bool(self.mem[reg + 6] & SM_ACTIVATE_REPEAT)
        # The firmware takes a pending state request before an SM change (SOES runs
        # ESC_state() before ESC_sm_act_event() in every pass): mailbox SMs cleared right
        # after a request for INIT are looked at in INIT, where no mailbox runs.
        upcoming = self._transition[1] if self._transition is not None else None
        refusal = (self._check_mailbox() if not self.device_emulation
                   and self._mailbox_running(upcoming) else None)
        if refusal is not None:
            # The mailbox SMs no longer as the firmware set them up: it stops the mailbox
            # and falls back to INIT with 0x0016, 0x0015 in BOOT (SOES ESC_sm_act_event,
            # ESC_checkmbx).  It never writes a reply into an area the master moved (over
            # registers, past the end of memory).
            self._stop_mailbox()
            self._refuse(AlState.INIT, refusal)
        elif sm.number == self._mbx_in and request != was_repeat:
            # Repeat: post the last message again (the master lost it) and acknowledge.
            # Before PREOP the mailbox is not running: the bit is only taken over
            # (SOES ESC_startmbx copies it when the mailbox starts).
            sm.repeat_request = request
            if self.last_mailbox is not None and self._mailbox_running():
                self._post(sm, self.last_mailbox)
        if not sm.full and sm.number == self._mbx_in:
            self._post_next()
        sm.store_status(self.mem)
        if self.on_mapping_change:
            self.on_mapping_change()

    def _mailbox_running(self, state: int | None = None) -> bool:
        """Whether the mailbox runs in ``state`` (default: the state AL status shows)."""
        if state is None:
            state = self.mem[Reg.AL_STATUS] & AL_STATE_MASK
        return state in (AlState.PREOP, AlState.BOOT, AlState.SAFEOP, AlState.OP)

    def _stop_mailbox(self) -> None:
        self.mailbox_queue.clear()
        self._replies.clear()
        self._reply_starts.clear()
        self.last_mailbox = None

    def _write_sm_area(self, sm: SmState, ado: int, data: bytes | memoryview) -> bool:
        n = len(data)
        if ado < sm.start or ado + n > sm.end:
            return False                       # an access must lie inside the SM window
        if sm.is_mailbox:
            if not sm.master_writes or sm.full:
                return False
            self.mem[ado:ado + n] = data
            if ado + n == sm.end:
                sm.read_event = True        # the firmware reads the buffer out at once
                sm.store_status(self.mem)
                self._mailbox_received(bytes(self.mem[sm.start:sm.end]))
            return True
        if not sm.master_writes:
            return False
        self.mem[ado:ado + n] = data
        if ado + n == sm.end:
            self.outputs_written()
        return True

    def _read_mailbox(self, sm: SmState, ado: int, n: int) -> bytes | None:
        if sm.master_writes or not sm.full or ado < sm.start or ado + n > sm.end:
            return None
        data = bytes(self.mem[ado:ado + n])
        if ado + n == sm.end:
            sm.full = False
            sm.read_event = True
            sm.store_status(self.mem)
            self._post_next()
        return data

    def _mailbox_in_sm(self) -> SmState | None:
        """The firmware's mailbox-in SM while it is running (configured as the ESI says:
        checked at INIT->PREOP and at every SM change after that)."""
        if self._mbx_in is None or not self._mailbox_running():
            return None
        sm = self.sms[self._mbx_in]
        return sm if sm.active and sm.kind is SmKind.MAILBOX_IN else None

    def _mailbox_received(self, message: bytes) -> None:
        """The firmware takes the message out of SM0 at once (the buffer is empty again)
        and queues its answers for SM1."""
        state = self.state
        if state is None or state == AlState.INIT or self.mailbox is None:
            return
        replies = self.mailbox.handle(message, state)
        if replies and self.timing and self.timing.mailbox_reply_ns:
            # The firmware answers after its reply latency (runtime/segment/timing.py), one
            # message at a time: a request taken while it still works on the one before
            # (a master that writes SM0 before reading SM1) waits for that one first.
            now = self.clock_ns()
            if self._replies:
                now = max(now, self._replies[-1][0])
            self._replies.append((now + self.timing.mailbox_reply_ns, replies))
            start = self.timing.reply_start_ns
            if start is not None and start < self.timing.mailbox_reply_ns:
                self._reply_starts.append(now + start)
            return
        self.mailbox_queue.extend(replies)
        self._post_next()

    def _post_next(self) -> None:
        sm = self._mailbox_in_sm()
        if sm is None or sm.full or not self.mailbox_queue:
            return
        self._post(sm, self.mailbox_queue.popleft())

    def _post(self, sm: SmState, message: bytes) -> None:
        body = message[:sm.length]
        self.mem[sm.start:sm.end] = body + bytes(sm.length - len(body))
        self.last_mailbox = message
        sm.full = True
        sm.read_event = False
        sm.store_status(self.mem)

    # -- process data ------------------------------------------------------------------------

    def outputs_written(self, now: float | None = None) -> None:
        """A complete write of an output SM (feeds the SM watchdog).  A write after a gap
        longer than the watchdog time finds it expired first: the ESC's watchdog counts
        down between the two writes whenever they come (ESC Section II, 0x0420), not only
        when the segment's loop looks (every few ms, ``check_watchdog``), so a watchdog
        shorter than the loop's period expires as on hardware."""
        now = self.clock_ns() / 1e9 if now is None else now
        self.check_watchdog(now)
        self._last_output_write = now
        self.outputs_valid = True
        self._watchdog_expired = False
        self.mem[Reg.WATCHDOG_STATUS] = 1

    def process_sms(self, kind: SmKind) -> list[SmState]:
        return [sm for sm in self.sms if sm.active and sm.kind is kind]

    def outputs(self) -> bytes:
        """The outputs the application sees: the output SMs' data in OP, zeros otherwise
        (a slave keeps its outputs safe below OP)."""
        sms = self.process_sms(SmKind.OUTPUTS)
        data = b"".join(bytes(self.mem[sm.start:sm.end]) for sm in sms)
        return data if self.state == AlState.OP else bytes(len(data))

    def set_inputs(self, data: bytes) -> None:
        """Fill the input SMs (in SM order) with ``data``, as the application would."""
        pos = 0
        for sm in self.input_areas():
            chunk = data[pos:pos + sm[1]]
            self.mem[sm[0]:sm[0] + len(chunk)] = chunk
            pos += sm[1]

    def input_layout(self) -> list[tuple[int, int, int, int]]:
        """(bit address in ESC memory, index, subindex, bit length) of each entry in the
        input SMs as the slave lays them out now: from its current assignment and mapping
        (0x1C1n, 0x1Axx) where its dictionary holds valid ones, else from the ESI's default
        PDOs; the SM where the master configured it, else where the ESI places it.
        Padding has index 0."""
        configured = {sm.number: sm.start for sm in self.process_sms(SmKind.INPUTS)}
        out: list[tuple[int, int, int, int]] = []
        for sm in self.device.sms:
            if sm.type != "Inputs" or sm.virtual:
                continue
            entries = self.od.sm_entries(sm.number) if self.od is not None else None
            if entries is None:
                entries = [(e.index or 0, e.subindex or 0, e.bit_len or 0)
                           for p in self.device.tx_pdos if p.sm == sm.number and not p.virtual
                           for e in p.entries]
            bit = 8 * configured.get(sm.number, sm.start_address or 0)
            for index, sub, bits in entries:
                out.append((bit, index, sub, bits))
                bit += bits
        return out

    def hold_input(self, index: int, sub: int, bits: int, value: int) -> None:
        """Hold an input entry at ``value`` (``bits`` wide, two's complement when negative),
        as the device's application would set it (a button pressed), and put it in place."""
        self.held_inputs[(index, sub)] = (bits, value & ((1 << bits) - 1))
        self.apply_held_inputs()

    def release_input(self, index: int, sub: int) -> None:
        self.held_inputs.pop((index, sub), None)

    def apply_held_inputs(self) -> None:
        """Write each held input where the current mapping places it (a master that maps
        other PDOs moves it, as firmware would); an entry not mapped now is not written."""
        if not self.held_inputs:
            return
        for bit, index, sub, bits in self.input_layout():
            held = self.held_inputs.get((index, sub))
            if held is None or index == 0:
                continue
            value = held[1] & ((1 << bits) - 1)
            for k in range(bits):
                byte, mask = (bit + k) >> 3, 1 << ((bit + k) & 7)
                if byte >= len(self.mem):
                    break
                if value >> k & 1:
                    self.mem[byte] |= mask
                else:
                    self.mem[byte] &= ~mask & 0xFF

    def input_areas(self) -> list[tuple[int, int]]:
        """(start, length) of each input SM: configured ones, or the ESI's before that."""
        active = self.process_sms(SmKind.INPUTS)
        if active:
            return [(sm.start, sm.length) for sm in active]
        return [(sm.start_address or 0, (bits + 7) // 8) for sm in self.device.sms
                if sm.type == "Inputs" and (bits := self._expected_pd.get(sm.number, 0))]

    def check_watchdog(self, now: float) -> None:
        """SM watchdog: in OP, outputs that stop arriving for longer than the watchdog time
        expire it once: the ESC clears the watchdog status (0x0440 bit 0) and counts the
        expiry (0x0442, stops at 0xFF) (ESC Section II).  Firmware then takes the slave to
        SAFEOP+ERR 0x001B and clears its outputs.  A device-emulation ESC cannot change
        AL status: the state stays OP, and with the digital I/O PDI the ESC resets the
        output pins (Beckhoff, "General notes for setting the watchdog": the SM watchdog
        sets the outputs to FALSE, the state of the terminal remains unaffected).  Runs every
        few milliseconds for every slave: the limit is worked out when the slave enters OP."""
        limit = self._watchdog_limit
        if (limit is None or self.mem[Reg.AL_STATUS] & AL_STATE_MASK != AlState.OP
                or self._watchdog_expired):
            return
        if now - self._last_output_write > limit:
            self._watchdog_expired = True
            self.mem[Reg.WATCHDOG_STATUS] &= 0xFE
            self.mem[Reg.WATCHDOG_COUNTER_SM] = min(self.mem[Reg.WATCHDOG_COUNTER_SM] + 1, 0xFF)
            self.outputs_valid = False
            if self.device_emulation and self.mem[Reg.PDI_CONTROL] != PDI_DIGITAL_IO:
                return          # no firmware and no pins: nothing else reacts
            for sm in self.process_sms(SmKind.OUTPUTS):
                self.mem[sm.start:sm.end] = bytes(sm.length)
            if not self.device_emulation:
                self._refuse(AlState.SAFEOP, Refusal(AlStatusCode.SM_WATCHDOG,
                                                     Rule.SM_WATCHDOG, "outputs stopped"))

    def _arm_watchdog(self) -> None:
        """The SM watchdog time (0x0420 x (0x0400 + 2) x 40 ns), or None when no output SM
        has its watchdog enabled (control bit 6) or the time is 0."""
        self._watchdog_limit = None
        watched = [sm for sm in self.process_sms(SmKind.OUTPUTS)
                   if sm.control & SM_WATCHDOG_ENABLE]
        divider, = struct.unpack_from("<H", self.mem, Reg.WATCHDOG_DIVIDER)
        time_units, = struct.unpack_from("<H", self.mem, Reg.WATCHDOG_SM)
        if watched and time_units:
            self._watchdog_limit = time_units * watchdog_base_ns(divider) * 1e-9

    # -- AL state machine --------------------------------------------------------------------

    def _al_control(self) -> None:
        control = struct.unpack_from("<H", self.mem, Reg.AL_CONTROL)[0]
        if self.device_emulation:
            self._mirror_al_control(control)
            return
        self._state_request(control)
        self._id_request(control)

    def _id_request(self, control: int) -> None:
        """Explicit device identification (ETG.1020 "Requesting ID"; ESC Section II AL
        control/status bit 5, AL status code 0x0134): while the master's AL control has
        bit 5 set, the firmware shows its ID (``device_id``, an ID switch) in 0x0134 and
        sets AL status bit 5; when the master clears the bit, AL status bit 5 clears and
        0x0134 holds the AL status code again.  A device without an ID ignores the
        request (bit 5 stays 0, the code stays), and an error indication keeps its code:
        the master acknowledges the error first."""
        want = bool(control & AL_ID_REQUEST) and self.device_id is not None
        if want == self._id_shown or (want and self.error):
            return
        self._id_shown = want
        status = self.al_status & ~AL_STATUS_ID | (AL_STATUS_ID if want else 0)
        struct.pack_into("<H", self.mem, Reg.AL_STATUS, status)
        shown = self.device_id if want and self.device_id is not None else self._al_code
        struct.pack_into("<H", self.mem, Reg.AL_STATUS_CODE, shown & 0xFFFF)

    def _state_request(self, control: int) -> None:
        """The state bits of an AL control write: the firmware's state machine."""
        requested = control & AL_STATE_MASK
        if self._transition is not None:
            if requested == self._transition[1]:
                return              # already on its way there
            self._transition = None  # a new request replaces the one in progress
        ack = bool(control & AL_ERROR_ACK)
        current = self.state
        if current is None:
            # AL status is read-only from EtherCAT (any command, FMMUs included) and the
            # firmware only ever sets states; should it hold none, the firmware starts
            # over from INIT, as after a reset, and says the state is unknown.
            self._refuse(AlState.INIT, Refusal(AlStatusCode.UNKNOWN_STATE,
                                               Rule.UNKNOWN_STATE, "AL status held no state"))
            return
        if self.error:
            if not ack and requested != AlState.INIT:
                return              # an error must be acknowledged first (SOES, KickCAT)
            if ack:
                self.mem[Reg.AL_STATUS] &= ~AL_STATUS_ERROR & 0xFF
        if requested not in AlState.__members__.values():
            self._refuse(AlState.SAFEOP if current == AlState.OP else current,
                         Refusal(AlStatusCode.UNKNOWN_STATE, Rule.UNKNOWN_STATE,
                                 f"0x{requested:X} requested"))
            return
        target = AlState(requested)
        if target == current:
            return
        moving = f"{current.name}->{target.name}"
        if target == AlState.BOOT and not self.boot_supported:
            self._refuse(current, Refusal(AlStatusCode.BOOT_NOT_SUPPORTED, Rule.BOOT_UNSUPPORTED,
                                          moving) if current == AlState.INIT
                         else Refusal(AlStatusCode.INVALID_STATE_CHANGE, Rule.STATE_CHANGE,
                                      moving))
            return
        if target != AlState.INIT and (current, target) not in _ALLOWED:
            self._refuse(current, Refusal(AlStatusCode.INVALID_STATE_CHANGE,
                                          Rule.STATE_CHANGE, moving))
            return
        transition = _LETTER[current] + _LETTER[target]
        injected = self.refuse.get(transition)
        refusal = (Refusal(injected, Rule.INJECTED, transition) if injected
                   else self._check(current, target))
        if refusal is not None:
            self._refuse(current if target > current else target, refusal)
            return
        delay = self.timing.transition_ns(transition) if self.timing else 0
        if delay:
            # AL status keeps the old state until the firmware is done (runtime/segment/timing.py).
            self._transition = (self.clock_ns() + delay, target)
            return
        self._enter(target)

    def _refuse(self, state: AlState, refusal: Refusal) -> None:
        self.refusal = refusal
        self._set_state(state, refusal.code)

    def _check(self, current: AlState, target: AlState) -> Refusal | None:
        """The refusal of ``current`` -> ``target``, or None."""
        if current == AlState.INIT and target == AlState.PREOP:
            return self._check_mailbox()
        if current == AlState.INIT and target == AlState.BOOT:
            return al_checks.bootstrap_refusal(self.bootstrap_mailbox, self.sms)
        if current == AlState.PREOP and target == AlState.SAFEOP:
            return (self._check_process_data(op=False) or self._check_dc()
                    or self._check_soe())
        if current == AlState.SAFEOP and target == AlState.OP:
            return self._check_process_data(op=True)
        return None

    def _check_mailbox(self) -> Refusal | None:
        if self.state == AlState.BOOT:
            return al_checks.bootstrap_refusal(self.bootstrap_mailbox, self.sms)
        return al_checks.mailbox_refusal(self.device, self.sms)

    @property
    def bootstrap_mailbox(self) -> tuple[int, int, int, int]:
        """The bootstrap mailbox the firmware uses, as its SII gives it (words 0x14-0x17:
        receive offset, size, send offset, size; ETG.2010)."""
        words = self.eeprom[2 * SII_BOOTSTRAP_MAILBOX:2 * SII_BOOTSTRAP_MAILBOX + 8]
        if len(words) < 8:
            return (0, 0, 0, 0)
        rx, rx_size, tx, tx_size = struct.unpack("<4H", words)
        return rx, rx_size, tx, tx_size

    @property
    def boot_supported(self) -> bool:
        """BOOT needs a boot loader: here, an FoE server and a bootstrap mailbox in the
        SII (otherwise the firmware refuses with 0x0013, bootstrap not supported)."""
        return (self.mailbox is not None and self.mailbox.foe is not None
                and self.mailbox.boot_sizes is not None)

    def _pd_bits(self, why: dict[int, tuple[Rule, str]] | None = None
                 ) -> dict[int, int | None]:
        """Process-data bits per SM that the slave's current PDO assignment needs (None
        where it cannot be used: ``why`` gets the rule and the values)."""
        if self.od is None:
            return dict(self._expected_pd)
        out: dict[int, int | None] = {}
        for n in self._expected_pd:
            entries, problem = self.od.assignment(n)
            out[n] = None if entries is None else sum(bits for _, _, bits in entries)
            if problem is not None and why is not None:
                why[n] = problem
        return out

    def _check_process_data(self, op: bool) -> Refusal | None:
        why: dict[int, tuple[Rule, str]] = {}
        return al_checks.process_data_refusal(self.device, self.sms, self.fmmus,
                                              self._pd_bits(why), self._internal_sms, op, why)

    def _check_dc(self) -> Refusal | None:
        return al_checks.dc_refusal(self.mem, self._min_cycle_ns())

    def _min_cycle_ns(self) -> int:
        """The minimum cycle time the slave's dictionary reports (0x1C32:05, 0x1C33:05;
        the larger), 0 without one."""
        found = [0]
        for index in (SM_OUTPUT_PARAMETER, SM_INPUT_PARAMETER):
            if self.od is not None and index in self.od \
                    and SM_PARAMETER_MIN_CYCLE in self.od[index].entries:
                found.append(self.od.int_value(index, SM_PARAMETER_MIN_CYCLE))
        return max(found)

    def _check_soe(self) -> Refusal | None:
        soe = self.mailbox.soe if self.mailbox is not None else None
        return al_checks.soe_refusal(soe) if soe is not None else None

    def _mirror_al_control(self, control: int) -> None:
        """Device emulation: the ESC copies the AL control word into AL status, every bit
        as written (state, the error-acknowledge bit as the error flag, device
        identification, the reserved bits), whatever the state: no transition rules, no
        SM, FMMU, mailbox or DC checks, no refusal codes, and 0x0134 untouched (Beckhoff
        ESC Section II, AL Control 0x0120 note; Section I "Device Emulation").  A real
        EK1100 and EL1004 read back 0x0011 after SOEM's 0x0011 (ethercrab-rs/ethercrab
        dumps/soem-sdinfo-ek1100-el1004.pcapng).  A refusal injected with ``refuse`` is
        still given: fault injection asks for a slave that refuses, whatever its ESC."""
        old = self.mem[Reg.AL_STATUS] & AL_STATE_MASK
        new = control & AL_STATE_MASK
        if old in _STATES and new in _STATES and old != new:
            transition = _LETTER[_STATES[old]] + _LETTER[_STATES[new]]
            code = self.refuse.get(transition)
            if code:
                target = _STATES[new]
                self._refuse(_STATES[old] if target > old else target,
                             Refusal(code, Rule.INJECTED, transition))
                return
        before = self.al_status
        self._state_effects(old, new)
        struct.pack_into("<H", self.mem, Reg.AL_STATUS, control)
        state = _STATES.get(new)
        if self.on_state_change and state is not None and control != before:
            note = self._sm_length_note() if new == AlState.SAFEOP and old != new else ""
            self.on_state_change(StateChange(self.position, self.name, state,
                                             bool(control & AL_STATUS_ERROR),
                                             self.status_code, note))

    def _sm_length_note(self) -> str:
        return al_checks.sm_length_note(self.sms, self._expected_pd)

    def _state_effects(self, old: int, new: int) -> None:
        """What follows a state (``old`` -> ``new``, raw AL status state bits): outputs
        are valid in SAFEOP and OP only, the SM watchdog runs from OP, the mailbox stops in
        INIT and restarts empty in INIT->PREOP."""
        if new not in RUNNING_STATES:
            self.outputs_valid = False
        if new == AlState.OP and old != AlState.OP:
            self._last_output_write = self.clock_ns() / 1e9
            self._watchdog_expired = False
            self._arm_watchdog()
        if new == AlState.INIT:
            self._stop_mailbox()
        if new in (AlState.PREOP, AlState.BOOT) and old == AlState.INIT:
            self.last_mailbox = None
            if self.mailbox is not None:
                self.mailbox.reset()

    def _enter(self, target: AlState) -> None:
        self._state_effects(self.mem[Reg.AL_STATUS] & AL_STATE_MASK, target)
        self._set_state(target, 0)

    def _set_state(self, state: AlState, code: int) -> None:
        self._transition = None
        self._al_code = code
        if code:
            self._id_shown = False          # an error shows its code, not the ID
        status = int(state) | (AL_STATUS_ERROR if code else 0) | (
            AL_STATUS_ID if self._id_shown else 0)
        struct.pack_into("<H", self.mem, Reg.AL_STATUS, status)
        struct.pack_into("<H", self.mem, Reg.AL_STATUS_CODE,
                         self.device_id if self._id_shown and self.device_id is not None
                         else code)
        if self.on_state_change:
            self.on_state_change(StateChange(self.position, self.name, state, bool(code),
                                             code))

    # -- distributed clocks ------------------------------------------------------------------

    def _dc_now(self) -> int:
        """The segment time at which the current frame passes this slave's processing unit
        (the segment holds its clock still while a frame passes)."""
        return self.clock_ns() + self.dc.port0_ns

    def local_time(self) -> int:
        return self.dc.local(self._dc_now())

    def system_time(self) -> int:
        """The local copy of system time: local time + offset (0x0920)."""
        offset: int = struct.unpack_from("<q", self.mem, 0x0920)[0]
        return (self.local_time() + offset) & 0xFFFF_FFFF_FFFF_FFFF

    def _ecat_system_time(self) -> int:
        """0x0910 as the wire reads it: the local copy of system time when the frame passed
        the reference clock, local time + offset - delay (ESC Section I, Table 30), so a
        synchronised line answers one value."""
        delay: int = struct.unpack_from("<I", self.mem, 0x0928)[0]
        return (self.system_time() - delay) & 0xFFFF_FFFF_FFFF_FFFF

    def latch_receive_times(self, times: tuple[int | None, ...]) -> None:
        """A write to 0x0900 passed: the ESC latches when the frame arrived at each port
        (local time; a port the frame did not reach keeps its last value, as IgH's
        "bypassed" check expects) and at the processing unit (0x0918)."""
        for port, t in enumerate(times[:4]):
            if t is not None:
                struct.pack_into("<I", self.mem, 0x0900 + 4 * port, t & 0xFFFF_FFFF)
        struct.pack_into("<Q", self.mem, 0x0918, (times[0] or 0) & 0xFFFF_FFFF_FFFF_FFFF)

    def _dc_registers_written(self, ado: int, n: int) -> None:
        if ado == Reg.DC_SYSTEM_TIME:
            self._system_time_written()
        if _overlaps(ado, n, Reg.DC_SPEED_COUNTER_START, Reg.DC_SPEED_COUNTER_START + 2):
            # A write of Speed Counter Start resets 0x092C and 0x0932 and the filters.
            self.dc.reset_loop(self._dc_now())
            self.mem[0x092C:0x0930] = bytes(4)
            self.mem[0x0932:0x0934] = bytes(2)
        if _overlaps(ado, n, Reg.DC_START_TIME_CYCLIC, Reg.DC_START_TIME_CYCLIC + 8):
            start, = struct.unpack_from("<Q", self.mem, Reg.DC_START_TIME_CYCLIC)
            now = self.system_time()
            if ado + n <= Reg.DC_START_TIME_CYCLIC + 4:         # 32-bit DC: low half
                lead = (start - now + (1 << 31)) % (1 << 32) - (1 << 31)
            else:
                lead = (start - now + (1 << 63)) % (1 << 64) - (1 << 63)
            self.sync0_start_lead_ns = lead

    def _system_time_written(self) -> None:
        """An ECAT write to 0x0910 (ARMW/FRMW from the reference clock) feeds the time
        control loop with the lower 32 bits (ESC Section I 9.1.5):
        dt = (local time + offset - delay) - received; 0x092C shows its mean, sign-magnitude
        with bit 31 set when the local copy is smaller (Section II)."""
        delay, = struct.unpack_from("<I", self.mem, 0x0928)
        received, = struct.unpack_from("<I", self.mem, Reg.DC_SYSTEM_TIME)
        t = self._dc_now()
        offset, = struct.unpack_from("<q", self.mem, 0x0920)
        own = self.dc.local(t) + offset - delay
        dt = (own - received + (1 << 31)) % (1 << 32) - (1 << 31)
        m = self.mem
        speed_start = struct.unpack_from("<H", m, Reg.DC_SPEED_COUNTER_START)[0] & 0x7FFF
        self.dc.sample(t, dt, speed_start, m[Reg.DC_TIME_FILTER] & 0x0F,
                       m[Reg.DC_TIME_FILTER + 1] & 0x0F)
        mean = int(round(self.dc.diff))
        struct.pack_into("<I", m, 0x092C,
                         min(abs(mean), 0x7FFF_FFFF) | (0x8000_0000 if mean < 0 else 0))
        struct.pack_into("<h", m, 0x0932, max(-0x8000, min(0x7FFF, self.dc.speed_counter_diff(
            speed_start))))
