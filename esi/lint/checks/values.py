"""ESI0xx: the file as a whole (parsing, unreadable values, identities, names)."""

from __future__ import annotations

from typing import Iterator

from ecatcfg.esi.lint.checks.common import repeats
from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, declare, file_rule
from ecatcfg.esi.model import ENGLISH, Device, format_selector

# Produced by the schema step and the runner, not by a check function.
XSD001 = declare("XSD001", "error", "the file does not validate against the ETG.2000 schema", """
    The ETG.2000 XML schema (EtherCATInfo.xsd or EtherCATModule.xsd from the folder given with
    --schema-dir, chosen by the root element) rejects the file at this place.  The message is
    libxml2's, with namespaces removed.  Configurators that validate on import (TwinCAT's ESI
    import, the ETG conformance tool) refuse such a file or silently drop the element.
    Without --schema-dir, the schema is not checked and lint says so once on stderr.""")

ESI001 = declare("ESI001", "error", "the file cannot be read as an ESI file", """
    The file is not well-formed XML (truncated, binary, wrong encoding), declares entities
    (refused: they enable external-entity reads and entity-expansion bombs), nests deeper
    than libxml2's limit, or its root element is neither EtherCATInfo nor EtherCATModule.
    The location is the parser's.  Nothing else is checked in such a file.""")


@file_rule("ESI002", "error", "a number is not a hex or decimal value, or does not fit its "
           "field", """
    ETG.2000 numbers (HexDecValue) are decimal ("4096") or hex with the "#x" prefix
    ("#x1000"); ecatcfg also accepts "0x".  This value is neither, or it does not fit what
    its field holds (a 16-bit SyncManager length, an 8-bit PDO entry subindex, a
    negative size, an object over 65535 bytes, more array elements than subindices 1..255;
    any number over 64 bits), so the reader left it unset: the device cannot be identified (Type/@ProductCode), a PDO entry cannot be placed,
    or a default is lost.  Typical causes: a stray "h" suffix ("1000h"), a digit group
    separator, a missing "#".""")
def unreadable_number(ctx: FileContext) -> Iterator[Hit]:
    for p in ctx.esi.problems:
        if p.kind == "number":
            yield Hit(p.source, p.message, p.column)


@file_rule("ESI003", "warning", "a binary, flag or enumerated value is not readable", """
    A hexBinary value (DefaultData, ConfigData, InitCmd/Data) has an odd number of digits or a
    non-hex character, a flag is not 0/1/true/false, or an access restriction names an
    unknown state.  The reader ignored the value.  Where it matters (InitCmd data, EEPROM
    config) the configurator cannot use the element at all.""")
def unreadable_value(ctx: FileContext) -> Iterator[Hit]:
    for p in ctx.esi.problems:
        if p.kind != "number":
            yield Hit(p.source, p.message, p.column)


@file_rule("ESI004", "error", "two devices in one file have the same product code and revision",
           """
    A configurator finds a device by vendor id, product code and revision number: the slave
    reports exactly these in its SII.  Two Device elements with the same pair in one file make
    the choice arbitrary (ecatcfg treats them as one device when they describe the same,
    and refuses the device when they differ, as for two files: ESI008).  Give each revision
    its own RevisionNo.""")
def duplicate_identity(ctx: FileContext) -> Iterator[Hit]:
    def identity(dev: Device) -> tuple[int, int] | None:
        if dev.product_code is None or dev.revision is None:
            return None
        return dev.product_code, dev.revision

    for dev, first in repeats(ctx.esi.devices, identity):
        yield Hit(dev.source, f"{dev.type_name!r} has the identity "
                  f"{format_selector(dev.vendor.id, dev.product_code, dev.revision)} already "
                  f"used by {first.type_name!r} at line {first.source.line}")


# Found across the files of one run, after each was linted (``esi/lint/across.py``).
ESI007 = declare("ESI007", "info", "another file describes the same device identically", """
    Another file given to lint has a Device with this vendor id, product code and revision,
    and the two describe the same device: they differ at most in what a master does not use
    (names, comments, images, the catalogue group, VendorSpecific tool data; numbers compared
    by value).  Configurators treat them as one device; ecatcfg compile and apply take either
    without a note.  Two copies of one vendor download, usually: keep one.""")

ESI008 = declare("ESI008", "error", "another file describes the same device differently", """
    Another file given to lint has a Device with this vendor id, product code and revision,
    and the two differ in what a master configures (PDOs and their entries, SyncManagers,
    FMMUs, mailbox, InitCmds, DC, the object dictionary, slots and modules); the message says
    what.  A slave reports only its identity, so a configurator cannot tell which file is
    right and a wrong pick gives a wrong process image.  ecatcfg compile and apply refuse the
    device until the topology names the file (esi: FILE) or the command ranks the files
    (--prefer).  Remove the outdated file, or give the devices their own revisions.""")


@file_rule("ESI005", "warning", "a name has no text in the default language", """
    ETG.2000 names are given per language (Name/@LcId); 1033 (English) is the default and the
    one configurators fall back to, and a Name without LcId counts as 1033.  This element has
    names, but none in 1033, so tools show another language or nothing.  Add a
    <Name LcId="1033">.  A Device or Vendor with no Name at all (IgH's ethercat xml leaves it
    out when the slave's SII has none, and never writes a vendor's) is shown by its Type or
    number only.""")
def missing_default_name(ctx: FileContext) -> Iterator[Hit]:
    esi = ctx.esi
    vendors = {id(d.vendor): d.vendor for d in esi.devices} or {0: esi.vendor}
    for vendor in vendors.values():
        if not vendor.names:
            number = "" if vendor.id is None else f" {vendor.id}"
            yield Hit(vendor.source, f"Vendor{number} has no Name")
    for dev in esi.devices:
        if not dev.names:
            yield Hit(dev.source, f"Device {dev.type_name!r} has no Name")
    owners = [("Vendor", esi.vendor.names, esi.vendor.source)]
    owners += [("Group", g.names, g.source) for g in esi.groups]
    owners += [("Module", m.names, m.source) for m in esi.modules]
    for dev in esi.devices:
        owners.append(("Device", dev.names, dev.source))
        owners += [(f"{p.direction.capitalize()}Pdo", p.names, p.source) for p in dev.pdos]
        if dev.slots:
            owners += [("Slot", s.names, s.source) for s in dev.slots.slots]
    for what, names, source in owners:
        if names and ENGLISH not in names:
            langs = ", ".join(str(k) for k in names)
            yield Hit(source, f"{what} has names only for LcId {langs}, none for 1033")


@file_rule("ESI006", "info", "an element the reader does not know was ignored", """
    The element is not defined by ETG.2000 at this place (a misspelt tag, an element of a
    newer schema version, a vendor extension outside VendorSpecific), so ecatcfg ignored it.
    If it carries configuration, that configuration is lost; vendor extensions belong in
    <VendorSpecific>.""")
def ignored_element(ctx: FileContext) -> Iterator[Hit]:
    for ig in ctx.esi.ignored:
        yield Hit(ig.source, f"<{ig.tag}> inside <{ig.parent}> is not an ETG.2000 element "
                  "there; ignored")
