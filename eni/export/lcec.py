"""The LinuxCNC export: the ``ethercat.xml`` that LinuxCNC's EtherCAT HAL driver (lcec,
linuxcnc-ethercat) reads, for the configuration :func:`ecatcfg.eni.export.igh.igh_config`
gives IgH (lcec is an IgH application: it makes the same ``ecrt_*`` calls from this file).

One ``<master>`` whose ``appTimePeriod`` is the ENI's cycle, with the ENI's DC reference
clock (``refClockSlaveIdx``) and ``refClockSyncCycles="1"`` when a slave uses DC; one
``<slave type="generic">`` per ENI slave with its ``vid``/``pid`` and, with
``configPdos="true"``, the ``<syncManager>``/``<pdo>``/``<pdoEntry>`` tree of its PDO
assignment and mapping; ``<dcConf>``, ``<watchdog>``, and the start-up SDOs as
``<sdoConfig>``/``<sdoDataRaw>`` in the ENI's order; SoE writes in an ``initCmds`` file
beside it (a TwinCAT start-up list, which lcec reads).  Every entry an ENI variable holds gets
a HAL pin (``halPin``, ``halType`` from the variable's type); a variable of several entries
gets a pin per entry, named after the variable and the entry.

The grammar is lcec's ``src/lcec_conf.c`` (``parseMasterAttrs``, ``parseSlaveAttrs``,
``parseDcConfAttrs``, ``parseWatchdogAttrs``, ``parseSdoConfigAttrs``,
``parseDataRawAttrs``, ``parseSyncManagerAttrs``, ``parsePdoAttrs``,
``parsePdoEntryAttrs``): indices, subindices, ``vid``, ``pid`` and ``assignActivate`` in
hex, the rest decimal.  What lcec cannot take is refused by :func:`check`.
"""

from __future__ import annotations

import re

from ecatcfg.eni.export.igh import IghConfig, IghSlave, PdoEntry, Registration, slave_error
from ecatcfg.esi import datatypes
from ecatcfg.record import record

# lcec_conf.h LCEC_CONF_STR_MAXLEN: a name is cut to 47 characters; a HAL name (HAL_NAME_LEN,
# LinuxCNC hal.h) is at most 47 in all: "lcec.<master>.<slave>.<pin>".
HAL_NAME_LEN = 47
MASTER_NAME = "0"
SLAVE_NAME_LEN = 16
# lcec_conf.c parsePdoEntryAttrs / parseSdoConfigAttrs: "tmp >= 0xff" and "tmp >= 0xffff"
# are refused, and bitLen is 1..LCEC_CONF_GENERIC_MAX_BITLEN (255).
MAX_SUBINDEX = 0xFE
MAX_INDEX = 0xFFFE
MAX_BIT_LEN = 255
# lcec_conf.h LCEC_CONF_GENERIC_MAX_SUBPINS: the bits of one complexEntry.
MAX_SUBPIN_BITS = 32
# lcec_generic.c: s32/u32 pins hold up to 32 bits; float-double-ieee 64.
_SIGNED = {"SINT", "INT", "INT24", "DINT"}


@record
class Pin:
    name: str                                 # halPin (none for "complex")
    hal_type: str                             # halType
    note: str                                 # the ENI variable (and entry) it stands for
    parts: list[tuple[int, str, str]] | None = None    # complexEntry: bits, halPin, halType


def hal_name(text: str) -> str:
    """``Term 1 (EL1008).Channel 1`` -> ``term-1-el1008.channel-1``: lower case, runs of
    other characters than letters and digits as ``-``, the ENI's dots kept."""
    parts = [re.sub(r"[^a-z0-9]+", "-", p.lower()).strip("-") for p in text.split(".")]
    return ".".join(p for p in parts if p) or "x"


def _fit(name: str, limit: int) -> str:
    """``name`` within ``limit`` characters, its last part (the entry's name) kept whole
    where it can be and the parts before it shortened."""
    if len(name) <= limit:
        return name
    head, _, last = name.rpartition(".")
    last = last[:limit]
    room = limit - len(last) - 1
    return f"{head[:room].rstrip('.-')}.{last}" if head and room >= 4 else last


def _unique(name: str, taken: set[str], limit: int) -> str:
    base = _fit(name, limit).rstrip(".-")
    out, n = base, 1
    while out in taken:
        n += 1
        out = f"{base[:limit - len(str(n)) - 1].rstrip('.-')}-{n}"
    taken.add(out)
    return out


def _hal_type(data_type: str | None, bits: int) -> str | None:
    """lcec's halType for an entry of ``bits`` of IEC type ``data_type`` (lcec_conf.c
    parsePdoEntryAttrs; lcec_generic.c reads s32/u32 of up to 32 bits)."""
    base = datatypes.canonical(data_type or "") or ""
    if bits == 1:
        return "bit"
    if base == "REAL" and bits == 32:
        return "float-ieee"
    if base == "LREAL" and bits == 64:
        return "float-double-ieee"
    if bits > 32:
        return None
    return "s32" if base in _SIGNED else "u32"


def _pins(file: str, slave: IghSlave, slave_name: str, regs: list[Registration]
          ) -> dict[tuple[int, int, int], Pin]:
    """The pin of each entry (SM, PDO place, entry place) a variable holds."""
    entries: dict[tuple[int, int, int], PdoEntry] = {
        (s.index, p, e): entry for s in slave.syncs for p, pdo in enumerate(s.pdos)
        for e, entry in enumerate(pdo.entries)}
    keys = [(x.index, x.subindex) for x in entries.values() if x.index]
    taken: set[str] = set()
    limit = HAL_NAME_LEN - len(f"lcec.{MASTER_NAME}.{slave_name}.")
    out: dict[tuple[int, int, int], Pin] = {}
    for r in regs:
        base = r.name[len(slave.name) + 1:] if r.name.startswith(slave.name + ".") else r.name
        # the entries of the variable: from its first (not a gap) back by its lead
        place = r.sync, r.pdo_pos, r.entry_pos
        first = place[2]
        while first > 0 and sum(entries[(r.sync, r.pdo_pos, k)].bit_len
                                for k in range(first - 1, place[2])) <= r.lead:
            first -= 1
        covered, bits = [], 0
        k = first
        while bits < r.bit_len:
            covered.append(k)
            bits += entries[(r.sync, r.pdo_pos, k)].bit_len
            k += 1
        whole = len(covered) == 1
        for k in covered:
            entry = entries[(r.sync, r.pdo_pos, k)]
            if not entry.index:
                continue                      # a gap: no pin
            where = f"variable {r.name!r}" + ("" if whole else f", entry {entry.name!r}")
            if keys.count((entry.index, entry.subindex)) > 1:
                raise slave_error(file, slave.position, slave.name,
                                  f"{where}: entry 0x{entry.index:04X}:{entry.subindex:02X} "
                                  f"is twice in the slave's PDOs, and lcec registers a pin's "
                                  f"entry by index and subindex (lcec_ethercat.c "
                                  f"lcec_pdo_init)")
            data_type = r.data_type if whole else entry.data_type
            hal_type = _hal_type(data_type, entry.bit_len)
            name = hal_name(base) if whole else f"{hal_name(base)}.{hal_name(entry.name)}"
            note = r.name if whole else f"{r.name}: {entry.name}"
            if hal_type is not None:
                out[(r.sync, r.pdo_pos, k)] = Pin(_unique(name, taken, limit), hal_type, note)
                continue
            # Wider than a HAL pin (an array of bytes, a 64-bit integer): a "complex" entry
            # of a pin per element, or per 32 bits (lcec_conf.c parseComplexEntryAttrs).
            element = datatypes.bit_size(_element_type(data_type)) or MAX_SUBPIN_BITS
            element = min(element, MAX_SUBPIN_BITS)
            stem = _unique(name, taken, limit - 1 - len(str(entry.bit_len // element)))
            parts = []
            for n, at in enumerate(range(0, entry.bit_len, element)):
                bits = min(element, entry.bit_len - at)
                parts.append((bits, _unique(f"{stem}.{n}", taken, limit),
                              "bit" if bits == 1 else "u32"))
            out[(r.sync, r.pdo_pos, k)] = Pin("", "complex", note, parts)
    return out


def _element_type(data_type: str | None) -> str:
    """The element type of ``ARRAY [a..b] OF T``, else the type itself."""
    base = datatypes.canonical(data_type or "") or ""
    match = re.match(r"^ARRAY \[-?\d+\.\.-?\d+\] OF (.+)$", base)
    return match.group(1) if match else base


def check(config: IghConfig, file: str) -> None:
    """Refuse what lcec's XML cannot say (the error names the slave and the command)."""
    for s in config.slaves:
        if s.eoe:
            raise slave_error(file, s.position, s.name,
                              f"{s.eoe.words}: lcec's XML has no EoE configuration")
        for sdo in s.sdos:
            if sdo.index > MAX_INDEX or sdo.subindex > MAX_SUBINDEX:
                raise slave_error(file, s.position, s.name,
                                  f"{sdo.words}: lcec's sdoConfig takes an idx below 0xFFFF "
                                  f"and a subIdx below 0xFF")
        for sync in s.syncs:
            for pdo in sync.pdos:
                for e in pdo.entries:
                    if e.subindex > MAX_SUBINDEX or e.index > MAX_INDEX or \
                            not 0 < e.bit_len <= MAX_BIT_LEN:
                        raise slave_error(file, s.position, s.name,
                                          f"PDO 0x{pdo.index:04X} entry "
                                          f"0x{e.index:04X}:{e.subindex:02X} of {e.bit_len} "
                                          f"bit: lcec's pdoEntry takes a subIdx below 0xFF "
                                          f"and 1 to 255 bits")


def _attr(value: object) -> str:
    return str(value).replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")


def _comment(text: str) -> str:
    """Text safe in an XML comment, on one line."""
    text = " ".join(text.split())
    while "--" in text:
        text = text.replace("--", "- -")
    return text.rstrip("-")


def slave_names(config: IghConfig) -> list[str]:
    taken: set[str] = set()
    return [_unique(hal_name(s.name).replace(".", "-"), taken, SLAVE_NAME_LEN)
            for s in config.slaves]


def initcmds_name(stem: str, slave: IghSlave) -> str:
    return f"{stem}_{slave.position}_soe.xml"


def initcmds(slave: IghSlave, header: str) -> bytes:
    """The slave's SoE writes as an ``initCmds`` file: the TwinCAT start-up list lcec reads
    (lcec_conf_icmds.c: ``EtherCATMailbox/SoE/InitCmds/InitCmd``, its Transition PS (or
    IP) an IDN of PREOP, SO one of SAFEOP).  lcec's own ``<idnConfig>`` cannot be used:
    lcec_conf.c ``parseIdnConfigAttrs`` tests the attribute name "drive" twice, so it reads
    no "state" and refuses an idnConfig without one."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', f"<!-- {_comment(header)} -->",
             "<EtherCATMailbox><SoE><InitCmds>"]
    for idn in slave.idns:
        lines += ["  <InitCmd>",
                  f"    <Transition>{'SO' if idn.safeop else 'PS'}</Transition>",
                  f"    <Comment>{_attr(_comment(idn.words))}</Comment>",
                  "    <OpCode>3</OpCode>",
                  f"    <DriveNo>{idn.drive_no}</DriveNo>",
                  f"    <IDN>{idn.idn}</IDN>",
                  "    <Elements>64</Elements>",
                  "    <Attribute>0</Attribute>",
                  f"    <Data>{idn.data.hex()}</Data>",
                  "  </InitCmd>"]
    lines += ["</InitCmds></SoE></EtherCATMailbox>", ""]
    return "\n".join(lines).encode("utf-8")


def render(config: IghConfig, file: str, eni_name: str, eni_sha256: str, version: str,
           stem: str = "ethercat") -> tuple[bytes, list[tuple[str, bytes]]]:
    """(the ``ethercat.xml`` of ``config`` (read from ``file``), [(initCmds file name, its
    text)] for the slaves with SoE writes, named after ``stem``); raises
    :class:`ExportError` for what lcec cannot take."""
    check(config, file)
    header = (f"SoE start-up list for lcec's initCmds, generated by ecatcfg {version} "
              f"(ecatcfg export, format lcec) from {eni_name}, sha256 {eni_sha256}.")
    extra = [(initcmds_name(stem, s), initcmds(s, header)) for s in config.slaves if s.idns]
    names = slave_names(config)
    dc = any(s.dc for s in config.slaves)
    reference = next((s.position for s in config.slaves if s.reference_clock), None)
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             f"<!-- LinuxCNC EtherCAT (lcec) configuration of {_comment(eni_name)}, "
             f"generated by ecatcfg {_comment(version)} (ecatcfg export, format lcec) "
             f"from {_comment(eni_name)}, sha256 {eni_sha256}. Do not edit: export the ENI "
             f"again. -->",
             "<masters>"]
    master = f'  <master idx="0" appTimePeriod="{config.cycle_ns}"'
    if dc:
        master += ' refClockSyncCycles="1"'
    if reference is not None:
        master += f' refClockSlaveIdx="{reference}"'
    lines.append(master + ">")
    for s, name in zip(config.slaves, names):
        regs = [r for r in config.registrations if r.position == s.position]
        pins = _pins(file, s, name, regs)
        lines.append(f"    <!-- slave {s.position}: {_comment(s.name)}, revision "
                     f"0x{s.revision:08X} (lcec checks vendor and product only) -->")
        for note in s.notes:
            lines.append(f"    <!-- {_comment(note)} -->")
        lines.append(f'    <slave idx="{s.position}" type="generic" vid="{s.vendor_id:08X}" '
                     f'pid="{s.product_code:08X}" configPdos="{"true" if s.syncs else "false"}" '
                     f'name="{_attr(name)}">')
        if s.idns:
            lines.append(f'      <initCmds filename="{_attr(initcmds_name(stem, s))}"/>')
        if s.dc:
            lines.append(f'      <dcConf assignActivate="{s.dc.assign_activate:X}" '
                         f'sync0Cycle="{s.dc.sync0_cycle}" sync0Shift="{s.dc.sync0_shift}" '
                         f'sync1Cycle="{s.dc.sync1_cycle}" sync1Shift="0"/>')
        if s.watchdog:
            lines.append(f'      <watchdog divider="{s.watchdog.divider}" '
                         f'intervals="{s.watchdog.intervals}"/>')
        for sdo in s.sdos:
            sub = "complete" if sdo.complete_access else f"{sdo.subindex:02X}"
            lines.append(f"      <!-- {_comment(sdo.words)} -->")
            lines.append(f'      <sdoConfig idx="{sdo.index:04X}" subIdx="{sub}">'
                         f'<sdoDataRaw data="{sdo.data.hex(" ").upper()}"/></sdoConfig>')
        for sync in s.syncs:
            lines.append(f'      <syncManager idx="{sync.index}" '
                         f'dir="{"out" if sync.output else "in"}">')
            for p, pdo in enumerate(sync.pdos):
                lines.append(f'        <pdo idx="{pdo.index:04X}">'
                             f"<!-- {_comment(pdo.name)} -->")
                for e, entry in enumerate(pdo.entries):
                    pin = pins.get((sync.index, p, e))
                    text = (f'          <pdoEntry idx="{entry.index:04X}" '
                            f'subIdx="{entry.subindex:02X}" bitLen="{entry.bit_len}"')
                    if pin is not None and pin.parts is not None:
                        lines.append(text + ' halType="complex">'
                                     f"<!-- {_comment(pin.note)} -->")
                        lines += [f'            <complexEntry bitLen="{bits}" '
                                  f'halPin="{_attr(part)}" halType="{kind}"/>'
                                  for bits, part, kind in pin.parts]
                        text = "          </pdoEntry>"
                    elif pin is not None:
                        text += (f' halPin="{_attr(pin.name)}" halType="{pin.hal_type}"/>'
                                 f"<!-- {_comment(pin.note)} -->")
                    else:
                        text += "/>" + (f"<!-- {_comment(entry.name)} -->"
                                        if entry.index else "<!-- gap -->")
                    lines.append(text)
                lines.append("        </pdo>")
            lines.append("      </syncManager>")
        lines.append("    </slave>")
    lines += ["  </master>", "</masters>", ""]
    return "\n".join(lines).encode("utf-8"), extra
