"""``ecatcfg sii build|show|read|write``: write the SII (EEPROM) image of an ESI device;
decode an image; read or program a slave's EEPROM on a line.

    ecatcfg sii build ESI --device SELECTOR -o FILE.bin [--serial N] [--alias N]
    ecatcfg sii show FILE.bin [--format text|json]
    ecatcfg sii read --iface IF --slave POS -o FILE.bin
    ecatcfg sii write --iface IF --slave POS FILE.bin [--force] [--backup FILE.bin]
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    from ecatcfg.esi.sii import SiiImage


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ecatcfg.cli.options import add_backup, add_line, add_prefer, number

    p = sub.add_parser("sii", help="build an SII (EEPROM) image from an ESI device, or "
                                   "decode one",
                       description="SII (slave EEPROM) images: build the image an ESI device "
                                   "describes, or decode an image (ours or a dump of a real "
                                   "EEPROM).")
    actions = p.add_subparsers(dest="sii_action", metavar="ACTION", required=True)

    b = actions.add_parser("build", help="write the SII image of one ESI device",
                           description="Write the EEPROM image of one device: config area "
                                       "and checksum, identity, mailbox, STRINGS, GENERAL, "
                                       "FMMU, SYNCM, the default PDO assignment and DC op "
                                       "modes, padded with 0xFF to Eeprom/ByteSize (2 KiB "
                                       "by default).")
    b.add_argument("esi", nargs="+", metavar="ESI", help="ESI file or folder (searched "
                                                         "recursively)")
    b.add_argument("--device", required=True, metavar="SELECTOR",
                   help="Type name or VENDOR:PRODUCT[:REVISION] (hex 0x.. or decimal)")
    add_prefer(b)
    b.add_argument("-o", "--output", required=True, metavar="FILE.bin",
                   help="image file to write")
    b.add_argument("--serial", type=number(0xFFFFFFFF), default=0, metavar="N",
                   help="serial number, SII words 0x0E-0x0F (default 0)")
    b.add_argument("--alias", type=number(0xFFFF), default=0, metavar="N",
                   help="configured station alias, SII word 4 (default 0)")
    b.add_argument("--no-cache", action="store_true",
                   help="do not read or write the ESI index cache")
    b.set_defaults(run=run)

    s = actions.add_parser("show", help="decode an SII image",
                           description="Decode an SII image: identity, config area and "
                                       "checksum, mailbox, strings, general, FMMUs, "
                                       "SyncManagers, PDOs and DC modes.")
    s.add_argument("image", metavar="FILE.bin", help="SII image (raw binary)")
    s.add_argument("--format", choices=("text", "json"), default="text")
    s.set_defaults(run=run)

    r = actions.add_parser("read", help="read a slave's EEPROM into a file",
                           description="Read the whole SII EEPROM of the slave at a position "
                                       "(its size from SII word 0x3E) through the ESC's "
                                       "EEPROM interface; nothing else is written.")
    add_line(r)
    r.add_argument("-o", "--output", required=True, metavar="FILE.bin",
                   help="image file to write")
    r.set_defaults(run=run)

    w = actions.add_parser(
        "write", help="program a slave's EEPROM from an image file",
        description="Program the SII EEPROM of the slave at a position: the current image "
                    "is read and saved first (the backup file is named in the output), an "
                    "image of another device (vendor, product, revision) is refused unless "
                    "--force, a wrong configuration-area checksum is fixed, the words that "
                    "differ are written one by one and everything is read back and "
                    "compared.  A write that stops part-way names the words written and "
                    "the backup to restore.",
        epilog="Exit 1 when the image is refused, the write stops or the read-back differs.")
    add_line(w)
    w.add_argument("image", metavar="FILE.bin", help="SII image (raw binary)")
    w.add_argument("--force", action="store_true",
                   help="write an image whose identity differs from the slave's")
    add_backup(w)
    w.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.sii_action == "build":
        return _build(args)
    if args.sii_action == "read":
        return _read(args)
    if args.sii_action == "write":
        return _write(args)
    return _show(args)


def _read(args: argparse.Namespace) -> int:
    from ecatcfg.cli.paths import messages, output_file
    from ecatcfg.errors import UsageError
    from ecatcfg.fileio import write_atomic

    out = output_file(args.output)
    from ecatcfg.cli.sii_program import open_eeprom
    with open_eeprom(args.iface, args.slave) as eeprom:
        data = eeprom.read()
    try:
        write_atomic(out, data)
    except OSError as exc:
        raise UsageError(f"cannot write {args.output}: {exc.strerror}") from None
    from ecatcfg.cli.sii_program import describe
    print(f"position {args.slave}: {describe(data)}; {len(data)} bytes written to {out} "
          f"({eeprom.reads} EEPROM reads)", file=messages(args.output))
    return 0


def _write(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ecatcfg.cli.sii_program import program
    from ecatcfg.errors import EcatcfgError, UsageError
    from ecatcfg.esi.sii import decode

    from ecatcfg.fileio import read_input

    path = Path(args.image)
    if not path.exists():
        raise UsageError(f"{args.image}: no such file")
    try:
        image = read_input(path, args.image)
    except OSError as exc:
        raise EcatcfgError(f"cannot read: {exc.strerror}", args.image) from None
    if len(image) % 2:
        raise EcatcfgError(f"{len(image)} bytes: an EEPROM image is whole 16-bit words",
                           args.image)
    decode(image, source=args.image)        # an SII image at all? (names file and offset)
    return program(args.iface, args.slave, image, backup=args.backup, force=args.force,
                   source=args.image)


def _build(args: argparse.Namespace) -> int:
    from ecatcfg.cli.paths import messages, output_file
    from ecatcfg.errors import EcatcfgError, UsageError
    from ecatcfg.esi import sii
    from ecatcfg.esi.library import Library
    from ecatcfg.fileio import write_atomic

    out = output_file(args.output)
    lib = Library(args.esi, cache=not args.no_cache, prefer=args.prefer)
    if lib.problems:
        for problem in lib.problems:
            print(f"error: {problem}", file=sys.stderr)
        raise EcatcfgError(f"{len(lib.problems)} ESI file problem(s); nothing written")
    selection = lib.find(args.device)
    for note in (selection.note, selection.preferred):
        if note:
            print(f"note: {note}", file=sys.stderr)
    device = lib.device(selection.entry)
    result = sii.build_image(device, serial=args.serial, alias=args.alias)
    where = f"{device.source.file}:{device.source.line}"
    for note in result.notes:
        level = "warning" if "more than" in note else "note"
        print(f"{level}: {where}: {device.type_name}: {note}", file=sys.stderr)
    try:
        write_atomic(out, result.data)
    except OSError as exc:          # name the user's file, not the temporary one beside it
        raise UsageError(f"cannot write {args.output}: {exc.strerror}") from None
    img = sii.decode(result.data)
    print(f"wrote {args.output}: {len(result.data)} bytes, {device.selector} "
          f"{device.type_name!r}, {len(img.categories)} categories, "
          f"{len(img.txpdos)} TxPDO / {len(img.rxpdos)} RxPDO", file=messages(args.output))
    return 0


def _show(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ecatcfg.errors import EcatcfgError, UsageError
    from ecatcfg.esi import sii
    from ecatcfg.fileio import read_input

    path = Path(args.image)
    if not path.exists():
        raise UsageError(f"{args.image}: no such file")
    try:
        data = read_input(path, args.image)
    except OSError as exc:
        raise EcatcfgError(f"cannot read: {exc.strerror}", args.image) from None
    img = sii.decode(data, source=args.image)
    if args.format == "json":
        json.dump({"file": args.image, **sii.to_json(img)}, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        render(img, args.image, sys.stdout)
    return 0


# -- text -----------------------------------------------------------------------------------

def render(img: SiiImage, name: str, out: TextIO) -> None:
    """The text form of a decoded image."""
    from ecatcfg.esi import sii
    from ecatcfg.esi.datatypes import COE_TYPE_NAMES

    w = out.write
    w(f"{name}: {img.data_size} bytes\n")
    w(f"identity     vendor 0x{img.vendor_id:08X}  product 0x{img.product_code:08X}  "
      f"revision 0x{img.revision:08X}  serial 0x{img.serial:08X}\n")
    crc = "ok" if img.checksum_ok else f"BAD, the config area gives 0x{img.checksum_computed:02X}"
    w(f"config area  PDI control 0x{img.pdi_control:04X}  PDI config 0x{img.pdi_config:04X}  "
      f"SYNC impulse {img.sync_impulse} x 10 ns  PDI config 2 0x{img.pdi_config2:04X}  "
      f"alias {img.alias}  checksum 0x{img.checksum:02X} {crc}\n")
    w(f"mailbox      standard rx (SM0) {_box(img.std_rx)}  tx (SM1) {_box(img.std_tx)};  "
      f"bootstrap rx {_box(img.bootstrap_rx)}  tx {_box(img.bootstrap_tx)}\n")
    w(f"protocols    {', '.join(img.protocols) or '-'} (0x{img.mailbox_protocols:04X})\n")
    end = f"END at 0x{img.end_offset:X}" if img.end_offset is not None else "no END marker"
    w(f"size         {img.eeprom_size_bytes} bytes (word 0x3E), version {img.version}; "
      f"{len(img.categories)} categories, {end}\n")
    w(f"strings      {len(img.strings)}\n")
    for n, text in enumerate(img.strings, 1):
        w(f"  {n:3}  {text!r}\n")
    g = img.general
    if g is not None:
        w("general\n")
        w(f"  group {_s(g.group, g.group_index)}  image {_s(g.image, g.image_index)}  "
          f"order {_s(g.order, g.order_index)}  name {_s(g.name, g.name_index)}\n")
        w(f"  CoE details 0x{g.coe_details:02X} ({_bits(g.coe_details, sii.COE_DETAIL_NAMES)})"
          f"  FoE {g.foe_details}  EoE {g.eoe_details}  SoE channels {g.soe_channels}  "
          f"DS402 channels {g.ds402_channels}  SysmanClass {g.sysman_class}\n")
        w(f"  flags 0x{g.flags:02X} ({_bits(g.flags, sii.GENERAL_FLAG_NAMES)})  EBus current "
          f"{g.ebus_current} mA  ports 0x{g.physical_ports:04X} ({' '.join(g.ports)})\n")
    if img.fmmus:
        w("FMMUs        " + ", ".join(f"{n} {sii.FMMU_TYPE_NAMES.get(t, f'0x{t:02X}')}"
                                      for n, t in enumerate(img.fmmus)) + "\n")
    if img.syncms:
        w("SyncManagers\n")
        for n, sm in enumerate(img.syncms):
            w(f"  SM{n}  0x{sm.start:04X}  length {sm.length:5}  control 0x{sm.control:02X}  "
              f"enable 0x{sm.enable:02X}  {sii.SM_TYPE_NAMES.get(sm.type, f'type {sm.type}')}"
              "\n")
    for label, pdos in (("TxPDO", img.txpdos), ("RxPDO", img.rxpdos)):
        for pdo in pdos:
            on = "no SM" if pdo.sm == sii.SM_UNASSIGNED else f"SM{pdo.sm}"
            flags = _bits(pdo.flags, sii.PDO_FLAG_NAMES)
            w(f"{label} 0x{pdo.index:04X}  {on}  {pdo.bit_length} bits  "
              f"{_s(pdo.name, pdo.name_index)}" + (f"  [{flags}]" if pdo.flags else "")
              + (f"  DC sync {pdo.dc_sync}" if pdo.dc_sync else "") + "\n")
            for e in pdo.entries:
                dtype = COE_TYPE_NAMES.get(e.data_type, f"0x{e.data_type:02X}")
                entry = "gap" if e.index == 0 else f"0x{e.index:04X}:{e.subindex:02X}"
                w(f"    {entry:12} {e.bit_len:3} bits  {dtype:8} {_s(e.name, e.name_index)}\n")
    if img.dc:
        w("DC modes\n")
        for mode in img.dc:
            w(f"  {_s(mode.name, mode.name_index)}  AssignActivate 0x{mode.assign_activate:04X}"
              f"  SYNC0 cycle {mode.cycle_time0} ns x{mode.sync0_cycle_factor} shift "
              f"{mode.shift_time0} ns  SYNC1 x{mode.sync1_cycle_factor} shift "
              f"{mode.shift_time1} ns\n")
    other = iter(img.other_categories)
    for cat in img.categories:
        if cat.decoded:
            continue
        _, data = next(other)
        label = sii.CATEGORY_NAMES.get(cat.type) or (
            "device specific" if 1 <= cat.type <= 9 else "vendor specific")
        more = " ..." if len(data) > 32 else ""
        w(f"category {cat.type} (0x{cat.type:04X}, {label}) at 0x{cat.offset:X}, "
          f"{cat.size} bytes: {data[:32].hex(' ')}{more}\n")


def _box(pair: tuple[int, int]) -> str:
    offset, size = pair
    return f"0x{offset:04X}/{size}" if offset or size else "-"


def _s(text: str | None, index: int) -> str:
    if index == 0:
        return "-"
    return f"{text!r} ({index})" if text is not None else f"#{index} (no such string)"


def _bits(value: int, names: dict[int, str]) -> str:
    parts = [name for bit, name in names.items() if value & bit]
    rest = value & ~sum(names)
    if rest:
        parts.append(f"0x{rest:X}")
    return ", ".join(parts) or "-"
