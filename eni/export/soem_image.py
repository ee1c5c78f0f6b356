"""Where SOEM puts each slave's process data and each variable in its IOmap.

SOEM does not take an ENI's logical addresses: ``ecx_config_map_group`` (SOEM
``ethercatconfig.c``, ``ecx_main_config_map_group`` with ``forceByteAlignment`` false, the
call pysoem's ``Master.config_map`` makes for group 0) lays the IOmap out by itself, and this
module derives that layout from the same rules (our own code; the functions cited are
SOEM's):

- all outputs first, then all inputs (the map is not overlapping): the output loop runs
  over the slaves in bus order, then the input loop, both from the same logical address
  and bit (``LogAddr``, ``BitPos``); the IOmap offset of a byte is its logical address
  (group 0 starts at 0).  After the outputs a partly used byte is closed
  (``if (BitPos) LogAddr++``), so the inputs start on a byte;
- a slave with 1 to 7 bits in a direction is *bit oriented* (``ecx_map_sm`` sets
  ``Obytes``/``Ibytes`` only for more than 7 bits): ``ecx_config_create_output_mappings``
  /``_input_mappings`` give it one FMMU from the current bit on, so its bits share a byte
  with the previous bit-oriented slave and may run into the next byte; ``Ostartbit`` /
  ``Istartbit`` is that first bit, and ``slave.outputs``/``.inputs`` point at its first
  byte;
- a slave with more bits is *byte oriented*: it starts on the next whole byte, its
  SyncManagers' bytes follow each other (each SM ``(bits + 7) / 8`` bytes long, as
  ``ecx_readPDOmap`` sizes it), capped at ``(bits + 7) / 8`` bytes in all (the FMMU size
  is cut at ``Obytes - FMMUdone``);
- ``segments`` (``IOsegment``) only split the LRW into frames; they move no data.

pysoem's ``slave.output``/``slave.input`` are ``Obytes``/``Ibytes`` long from that pointer,
one byte for a bit-oriented slave (pysoem ``_get_output``), so a bit of a bit-oriented slave
that runs into the next byte is only reachable through another slave whose bytes cover it
(:attr:`SoemImage.windows`).
"""

from __future__ import annotations

from typing import Literal

from ecatcfg.eni.export.steps import ExportError, ImageEntry, SlaveSetup
from ecatcfg.record import field, record

Direction = Literal["output", "input"]
DIRECTIONS: tuple[Direction, Direction] = ("output", "input")


@record
class SoemArea:
    """One slave's outputs or inputs in SOEM's IOmap."""

    slave: int                                # position, 0 = first
    direction: Direction
    bits: int                                 # Obits / Ibits
    iomap_byte: int                           # where slave.outputs / .inputs points
    start_bit: int                            # Ostartbit / Istartbit
    window: int                               # len(slave.output / .input) in pysoem

    @property
    def bit_oriented(self) -> bool:
        return self.bits < 8

    @property
    def span(self) -> int:
        """Bytes from the pointer that hold the slave's bits."""
        return (self.start_bit + self.bits + 7) // 8


@record
class SoemPlace:
    """A variable where SOEM puts it: ``byte`` from the slave's pointer (``slave.input`` /
    ``slave.output``), ``bit`` within that byte."""

    name: str
    slave: int
    direction: Direction
    byte: int
    bit: int
    bit_size: int
    data_type: str | None
    iomap_byte: int                           # the same byte from the IOmap's start


@record
class SoemImage:
    output_bytes: int                         # the IOmap's output part; inputs start here
    input_bytes: int
    areas: list[SoemArea] = field(default_factory=list)
    places: list[SoemPlace] = field(default_factory=list)

    def area(self, slave: int, direction: Direction) -> SoemArea | None:
        return next((a for a in self.areas if a.slave == slave and a.direction == direction),
                    None)

    def windows(self, direction: Direction) -> list[SoemArea]:
        return [a for a in self.areas if a.direction == direction]

    def reachable(self, place: SoemPlace) -> bool:
        """Whether pysoem's per-slave bytes cover every byte of the variable."""
        last = place.iomap_byte + (place.bit + place.bit_size - 1) // 8
        return all(any(a.iomap_byte <= b < a.iomap_byte + a.window
                       for a in self.windows(place.direction))
                   for b in range(place.iomap_byte, last + 1))


def _sm_bytes(ranges: list[int]) -> int:
    return sum((bits + 7) // 8 for bits in ranges)


def _place(setups: list[SlaveSetup], direction: Direction, log_addr: int,
           image: SoemImage) -> int:
    """Lay one direction out from byte ``log_addr`` (ecx_main_config_map_group's loop with
    ecx_config_create_output/input_mappings); the byte after it."""
    bit_pos = 0
    for s in setups:
        bits = s.output_bits if direction == "output" else s.input_bits
        if not bits:
            continue
        if bits < 8:                          # bit oriented: from the current bit on
            area = SoemArea(s.position, direction, bits, log_addr, bit_pos, 1)
            bit_pos += bits
            log_addr += bit_pos // 8
            bit_pos %= 8
        else:                                 # byte oriented: from the next whole byte
            if bit_pos:
                log_addr += 1
                bit_pos = 0
            size = (bits + 7) // 8
            area = SoemArea(s.position, direction, bits, log_addr, 0, size)
            log_addr += size
        image.areas.append(area)
    return log_addr + (1 if bit_pos else 0)


def soem_image(setups: list[SlaveSetup]) -> SoemImage:
    """SOEM's IOmap for the slaves' ``setups`` after ``ecx_config_map_group`` (group 0, not
    overlapping: what pysoem's ``config_map`` makes)."""
    image = SoemImage(0, 0)
    image.output_bytes = _place(setups, "output", 0, image)
    image.input_bytes = _place(setups, "input", image.output_bytes, image) - image.output_bytes
    for s in setups:
        for direction, entries in zip(DIRECTIONS, (s.outputs, s.inputs)):
            area = image.area(s.position, direction)
            for e in entries:
                assert area is not None
                at = area.start_bit + e.bit_offs
                image.places.append(SoemPlace(e.name, s.position, area.direction, at // 8,
                                              at % 8, e.bit_size, e.data_type,
                                              area.iomap_byte + at // 8))
    return image


def _outside(s: SlaveSetup, direction: Direction) -> ImageEntry | None:
    """The first variable SOEM leaves out of the slave's bytes: several SyncManagers whose
    whole bytes add up to more than ``(bits + 7) / 8`` (SOEM cuts the FMMUs there), or a
    bit-oriented slave with data in a second SyncManager (its one FMMU maps the first's)."""
    bits = s.output_bits if direction == "output" else s.input_bits
    entries = s.outputs if direction == "output" else s.inputs
    for e in entries:
        if e.bit_offs + e.bit_size > ((bits + 7) // 8 * 8 if bits >= 8 else bits):
            return e
    return None


def check(setups: list[SlaveSetup], file: str) -> None:
    """Refuse an ENI whose variables SOEM would not map (:func:`_outside`): the export
    would name bytes SOEM never exchanges."""
    for s in setups:
        for direction in DIRECTIONS:
            e = _outside(s, direction)
            if e is not None:
                bits = s.output_bits if direction == "output" else s.input_bits
                raise ExportError(f"slave {s.position} ({s.name!r}): {e.name}: SOEM maps "
                                  f"{bits} {direction} bits of this slave in "
                                  f"{max(1, (bits + 7) // 8)} byte(s), the ENI puts the "
                                  f"variable at bit {e.bit_offs} of its SyncManager data "
                                  "(several SyncManagers not filling whole bytes)", file)


def eni_note(s: SlaveSetup, area: SoemArea, image: SoemImage) -> str | None:
    """Where the ENI's own process image puts the slave's first bit, when that is not
    where SOEM puts it (relative to the start of the outputs, or of the inputs, in both):
    the export follows SOEM and says so."""
    ranges = s.send if area.direction == "output" else s.recv
    if not ranges:
        return None
    base = 0 if area.direction == "output" else image.output_bytes
    soem_bit = (area.iomap_byte - base) * 8 + area.start_bit
    eni_bit = ranges[0].bit_start
    if eni_bit == soem_bit:
        return None
    return (f"SOEM puts its {area.bits} {area.direction} bit(s) at IOmap byte "
            f"{area.iomap_byte} bit {area.start_bit} ({'O' if area.direction == 'output' else 'I'}"
            f"startbit {area.start_bit}); the ENI's {area.direction} image at byte "
            f"{eni_bit // 8} bit {eni_bit % 8}: the places here are SOEM's")
