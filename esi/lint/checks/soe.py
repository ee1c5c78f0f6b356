"""ESI216-ESI217: the SoE InitCmds of a drive (Mailbox/SoE/InitCmd, ETG.2000) that no
master can send as written.  They belong to the mailbox group (ESI2xx)."""

from __future__ import annotations

from typing import Iterator

from ecatcfg.esi.idn import idn_text
from ecatcfg.esi.lint.context import FileContext
from ecatcfg.esi.lint.rules import Hit, device_rule
from ecatcfg.esi.model import Device


@device_rule("ESI216", "error", "an SoE InitCmd has no IDN or no Data", """
    ETG.2000 requires both in Mailbox/SoE/InitCmd: the IDN says which drive parameter the
    master writes (S-0-0001 ...), Data the value.  Without one the write request (ETG.1000.6
    SoE, OpCode 3) cannot be made, and a master that left the command out would start the
    drive without a parameter its file asks for.  compile refuses the device, naming the
    command.  Write the IDN as its 16-bit number (32778 for P-0-0010) and the value as
    hexBinary in wire order (little-endian: d007 is 2000).""")
def soe_init_cmd_incomplete(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    soe = dev.mailbox.soe if dev.mailbox else None
    for cmd in soe.init_cmds if soe else []:
        if cmd.idn is None:
            yield Hit(cmd.source, "an SoE InitCmd without an IDN: no master knows which "
                      "parameter to write")
        elif cmd.data is None:
            yield Hit(cmd.source, f"the SoE InitCmd of {idn_text(cmd.idn)} has no Data: no "
                      "value to write")


@device_rule("ESI217", "error", "an SoE InitCmd is for a drive the device does not have", """
    InitCmd@Chn names the drive behind the slave that the write is for (the SoE header's
    drive number, 3 bits: 0-7, ETG.1000.6).  A slave with several drives (an AX5201 has
    two) says how many in Mailbox/SoE@ChannelCount; without it the slave has one drive, 0.
    A write to a drive beyond those is answered with an SoE error by the slave, and the
    transition fails; compile refuses the device, naming the command.""")
def soe_init_cmd_drive(dev: Device, ctx: FileContext) -> Iterator[Hit]:
    soe = dev.mailbox.soe if dev.mailbox else None
    if soe is None:
        return
    count = soe.drives
    for cmd in soe.init_cmds:
        if not 0 <= cmd.channel < count:
            what = idn_text(cmd.idn) if cmd.idn is not None else "an IDN"
            yield Hit(cmd.source, f"the SoE InitCmd of {what} is for drive {cmd.channel} "
                      f"(Chn), but the device has {count} drive{'s' if count != 1 else ''} "
                      "(ChannelCount)")
