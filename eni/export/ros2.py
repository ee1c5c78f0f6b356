"""The ROS 2 export: for ``ethercat_driver_ros2`` (ICube's ros2_control EtherCAT driver on
IgH), one generic-slave YAML per ENI slave and the ``<ros2_control>`` fragment that loads
them, one ``<gpio>`` per slave in bus order, for the configuration
:func:`ecatcfg.eni.export.igh.igh_config` gives IgH.

The YAML follows the driver's parser (``ethercat_generic_plugins`` ``GenericEcSlave::
setup_from_config``, ``ethercat_interface`` ``SdoConfigEntry``, ``SMConfig``,
``EcPdoChannelManager::load_from_config``): ``vendor_id``, ``product_id``,
``assign_activate``, ``sdo`` (index, sub_index, type, value), ``rpdo``/``tpdo`` (each PDO's
index and its channels: index, sub_index, type and the ``command_interface`` or
``state_interface`` named after the ENI variable) and ``sm`` (index, type, pdo, watchdog).

What the driver cannot take is refused (:func:`check`); a variable the driver has no
channel type for keeps its channel in the layout without an interface, and the YAML says
so in a comment beside it.
"""

from __future__ import annotations

from ecatcfg.eni.export.igh import IghConfig, IghSlave, PdoEntry, Registration, slave_error
from ecatcfg.eni.export.lcec import hal_name
from ecatcfg.esc import WATCHDOG_DIVIDER_DEFAULT, WATCHDOG_TIME_DEFAULT
from ecatcfg.esi import datatypes
from ecatcfg.record import record

# ec_pdo_channel_manager.hpp type2bits: the channel types and their bits; "bitN" any other
# size (a uint8_t: at most 255).
INTEGER_BITS = {8: "int8", 16: "int16", 32: "int32", 64: "int64"}
SIGNED = {"SINT", "INT", "DINT", "LINT"}
MAX_BIT_CHANNEL = 255
# ec_sdo_manager.hpp: the value is read as an int and written in 1, 2, 4 or 8 bytes of the
# type; an int holds 32 bits, so 8-byte values cannot be given.
SDO_TYPES = {1: "uint8", 2: "uint16", 4: "uint32"}


@record
class Channel:
    entry: PdoEntry
    type: str
    interface: str | None                     # state_interface / command_interface
    mask: int | None                          # for bool: the entry's bit in its byte
    note: str                                 # the ENI variable, or why it has no interface


def _channels(file: str, slave: IghSlave, regs: list[Registration]
              ) -> dict[tuple[int, int, int], Channel]:
    """Each entry's channel (SM, PDO place, entry place)."""
    by_place = {(r.sync, r.pdo_pos, r.entry_pos): r for r in regs}
    keys = [(e.index, e.subindex) for s in slave.syncs for p in s.pdos for e in p.entries
            if e.index]
    prefix = slave.name + "."
    taken: set[str] = set()
    out = {}
    for sync in slave.syncs:
        bit = 0                               # in the SM's data, which IgH lays from a byte
        for p, pdo in enumerate(sync.pdos):
            for e, entry in enumerate(pdo.entries):
                place = sync.index, p, e
                r = by_place.get(place)
                at = bit
                bit += entry.bit_len
                if not entry.index:
                    out[place] = Channel(entry, f"bit{entry.bit_len}", None, None, "gap")
                    continue
                if r is not None and keys.count((entry.index, entry.subindex)) > 1:
                    raise slave_error(file, slave.position, slave.name,
                                      f"variable {r.name!r}: entry 0x{entry.index:04X}:"
                                      f"{entry.subindex:02X} is twice in the slave's PDOs, "
                                      f"and the driver registers a channel by index and "
                                      f"subindex (ec_master.cpp registerPDOInDomain)")
                kind, why = _type(entry, r)
                if r is None or why:
                    out[place] = Channel(entry, kind, None, None,
                                         why or f"no ENI variable: {entry.name}")
                    continue
                base = r.name[len(prefix):] if r.name.startswith(prefix) else r.name
                name = hal_name(base)
                n, unique = 1, name
                while unique in taken:
                    n += 1
                    unique = f"{name}-{n}"
                taken.add(unique)
                out[place] = Channel(entry, kind, unique,
                                     1 << (at % 8) if kind == "bool" else None, r.name)
    return out


def _type(entry: PdoEntry, r: Registration | None) -> tuple[str, str]:
    """(the channel type, why the variable gets no interface or "")."""
    bits = entry.bit_len
    spans = r is not None and (r.bit_len != bits or r.lead != 0)
    data_type = (r.data_type if r is not None and not spans else entry.data_type) or ""
    base = datatypes.canonical(data_type) or ""
    kind = "bool" if bits == 1 else \
        (INTEGER_BITS[bits] if base in SIGNED else "u" + INTEGER_BITS[bits]) \
        if bits in INTEGER_BITS and base not in ("REAL", "LREAL") else f"bit{bits}"
    if r is not None and spans:
        return kind, (f"not an interface: {r.name} ({r.data_type or 'no type'}, {r.bit_len} "
                      f"bit) spans several entries; the driver reads one entry per channel")
    if not kind.startswith("bit") or kind == "bool":
        return kind, ""
    why = ""
    if r is not None:
        why = (f"not an interface: {r.name} ({data_type or 'no type'}, {bits} bit): the "
               f"driver reads integers of 8, 16, 32 and 64 bits and single bits")
    return kind, why


def check(config: IghConfig, file: str) -> None:
    """Refuse what the driver cannot be told (the error names the slave and what)."""
    dc_cycles = {s.dc.sync0_cycle for s in config.slaves if s.dc}
    for s in config.slaves:
        def refuse(what: str, s: IghSlave = s) -> None:
            raise slave_error(file, s.position, s.name, what)
        if s.idns:
            refuse(f"{s.idns[0].words}: the driver's generic slave has no SoE configuration")
        if s.eoe:
            refuse(f"{s.eoe.words}: the driver's generic slave has no EoE configuration")
        for sdo in s.sdos:
            if sdo.complete_access or len(sdo.data) not in SDO_TYPES:
                refuse(f"{sdo.words}: the driver's SDO configuration downloads 1, 2 or 4 "
                       f"bytes of one subindex (an int value, ec_sdo_manager.hpp)")
        if s.dc and (s.dc.sync0_shift or s.dc.sync1_cycle or len(dc_cycles) > 1):
            refuse(f"DC SYNC0 shift {s.dc.sync0_shift} ns, SYNC1 cycle {s.dc.sync1_cycle} ns: "
                   f"the driver gives ecrt_slave_config_dc the control period as SYNC0 "
                   f"cycle, its own shift and no SYNC1 (ec_master.cpp addSlave)")
        if s.watchdog and (s.watchdog.divider not in (0, WATCHDOG_DIVIDER_DEFAULT) or
                           s.watchdog.intervals not in (0, WATCHDOG_TIME_DEFAULT)):
            refuse(f"watchdog divider {s.watchdog.divider}, SM watchdog "
                   f"{s.watchdog.intervals}: the driver sets no watchdog times")
        outputs = [y for y in s.syncs if y.output and y.pdos]
        inputs = [y for y in s.syncs if not y.output and y.pdos]
        if len(outputs) > 1 or len(inputs) > 1:
            refuse("PDOs on two SyncManagers of one direction: the driver's sm list assigns "
                   "all rpdo to each output SM and all tpdo to each input SM")
        for y in s.syncs:
            for pdo in y.pdos:
                for e in pdo.entries:
                    if e.bit_len > MAX_BIT_CHANNEL:
                        refuse(f"PDO 0x{pdo.index:04X} entry 0x{e.index:04X}:"
                               f"{e.subindex:02X} of {e.bit_len} bit: a channel's bits are "
                               f"a uint8_t (type2bits)")


def yaml_name(stem: str, slave: IghSlave) -> str:
    return f"{stem}_{slave.position}_{hal_name(slave.name).replace('.', '-')}.yaml"


def _quote(text: str) -> str:
    """A YAML double-quoted scalar."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _comment(text: str) -> str:
    return " ".join(text.split())


def slave_yaml(file: str, config: IghConfig, slave: IghSlave, header: str) -> bytes:
    regs = [r for r in config.registrations if r.position == slave.position]
    channels = _channels(file, slave, regs)
    lines = [f"# {_comment(header)}",
             f"# slave {slave.position}: {_comment(slave.name)}, revision "
             f"0x{slave.revision:08X} (the driver checks vendor and product only)"]
    lines += [f"# {_comment(note)}" for note in slave.notes]
    lines += [f"vendor_id: 0x{slave.vendor_id:08x}", f"product_id: 0x{slave.product_code:08x}"]
    if slave.dc:
        lines.append(f"assign_activate: 0x{slave.dc.assign_activate:04x}")
    if slave.sdos:
        lines.append("sdo:  # downloaded once, before the master is activated")
        for sdo in slave.sdos:
            value = int.from_bytes(sdo.data, "little", signed=len(sdo.data) == 4)
            lines.append(f"  - {{index: 0x{sdo.index:04x}, sub_index: {sdo.subindex}, "
                         f"type: {SDO_TYPES[len(sdo.data)]}, value: {value}}}  "
                         f"# {_comment(sdo.words)}")
    for output in (True, False):
        syncs = [y for y in slave.syncs if y.output == output and y.pdos]
        if not syncs:
            continue
        lines.append("rpdo:" if output else "tpdo:")
        for pdo_pos, pdo in enumerate(syncs[0].pdos):
            lines += [f"  - index: 0x{pdo.index:04x}  # {_comment(pdo.name)}", "    channels:"]
            for e, entry in enumerate(pdo.entries):
                c = channels[(syncs[0].index, pdo_pos, e)]
                fields = [f"index: 0x{entry.index:04x}", f"sub_index: {entry.subindex}",
                          f"type: {c.type}"]
                if c.interface is not None:
                    key = "command_interface" if output else "state_interface"
                    fields.append(f"{key}: {_quote(c.interface)}")
                if c.mask is not None and c.interface is not None:
                    fields.append(f"mask: {c.mask}")
                lines.append(f"      - {{{', '.join(fields)}}}  # {_comment(c.note)}")
    if slave.syncs:
        lines.append("sm:")
        for y in slave.syncs:
            which = ("rpdo" if y.output else "tpdo") if y.pdos else "~"
            text = (f"  - {{index: {y.index}, type: {'output' if y.output else 'input'}, "
                    f"pdo: {which}")
            if y.watchdog is not None:
                text += f", watchdog: {'enable' if y.watchdog else 'disable'}"
            lines.append(text + "}")
    return ("\n".join(lines) + "\n").encode("utf-8")


def interfaces(file: str, config: IghConfig, slave: IghSlave) -> tuple[list[str], list[str]]:
    """(the command interfaces, the state interfaces) of the slave's gpio."""
    regs = [r for r in config.registrations if r.position == slave.position]
    channels = _channels(file, slave, regs)
    command: list[str] = []
    state: list[str] = []
    for (sm, _p, _e), c in sorted(channels.items()):
        if c.interface is not None:
            output = next(y.output for y in slave.syncs if y.index == sm)
            (command if output else state).append(c.interface)
    return command, state


def _attr(value: object) -> str:
    return str(value).replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")


def render(config: IghConfig, file: str, stem: str, eni_name: str, eni_sha256: str,
           version: str) -> tuple[bytes, list[tuple[str, bytes]]]:
    """(the ``<ros2_control>`` fragment, [(YAML file name, YAML)] in bus order)."""
    check(config, file)
    header = (f"ethercat_driver_ros2 generic slave configuration of {eni_name}, generated by "
              f"ecatcfg {version} (ecatcfg export, format ros2) from {eni_name}, sha256 "
              f"{eni_sha256}. Do not edit: export the ENI again.")
    files = [(yaml_name(stem, s), slave_yaml(file, config, s, header)) for s in config.slaves]
    frequency = 1e9 / config.cycle_ns
    lines = [f"<!-- ros2_control fragment for the EtherCAT network of "
             f"{_attr(eni_name).replace('--', '- -')}, generated by ecatcfg "
             f"{_attr(version)} (ecatcfg export, format ros2), sha256 {eni_sha256}. Each "
             f"slave_config names its file: give the path where it is installed. -->",
             f'<ros2_control name="{_attr(hal_name(stem))}" type="system">',
             "  <hardware>",
             "    <plugin>ethercat_driver/EthercatDriver</plugin>",
             '    <param name="master_id">0</param>',
             f'    <param name="control_frequency">{frequency:g}</param>',
             "  </hardware>"]
    for s, (name, _data) in zip(config.slaves, files):
        command, state = interfaces(file, config, s)
        ident = f"{s.position}_{hal_name(s.name).replace('.', '-')}"
        lines.append(f'  <gpio name="{_attr(ident)}">')
        lines += [f'    <command_interface name="{_attr(c)}"/>' for c in command]
        lines += [f'    <state_interface name="{_attr(c)}"/>' for c in state]
        lines += [f'    <ec_module name="{_attr(ident)}">',
                  "      <plugin>ethercat_generic_plugins/GenericEcSlave</plugin>",
                  '      <param name="alias">0</param>',
                  f'      <param name="position">{s.position}</param>',
                  f'      <param name="slave_config">{_attr(name)}</param>',
                  "    </ec_module>",
                  "  </gpio>"]
    lines += ["</ros2_control>", ""]
    return "\n".join(lines).encode("utf-8"), files
