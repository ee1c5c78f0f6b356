"""A slave's EoE IP parameters from the topology (``eoe:``), as the EoE InitCmd an ENI
carries: one set IP parameter request (ETG.1000.6 §5.7; layout in ``ecatcfg/eoe.py``) in
INIT->PREOP, written the way EC-Engineer writes it (``docs/eni-exports.md`` §9: the EoE
header in front of the fixed 58-byte body, comment "eoe init", ``Fixed``, timeout 0).  The
master sends it once the slave is in PREOP, after the transition's CoE InitCmds.

Checked here, at the slave's ``eoe`` line: the ESI must list EoE among the mailbox
protocols, a device whose ESI says ``<EoE IP="false">`` cannot take IP settings (a real one
answers 0x0201, no IP support), and SM0 must hold the request.  A device whose ESI has EoE
InitCmds of its own is an error at its ``device`` line: they are not implemented.
"""

from __future__ import annotations

import ipaddress
import struct
from typing import Protocol

from ecatcfg.compiler.topology import MAC_AUTO, Eoe
from ecatcfg.eni.plan import EoeInitCmd
from ecatcfg.eoe import IpParameters, encode_set_ip_request
from ecatcfg.esc import MAILBOX_HEADER_SIZE, Transition
from ecatcfg.esi.model import Device

COMMENT = "eoe init"            # EC-Engineer's comment (Murrelektronik VarioX export)
# EC-Engineer's made-up MAC: locally administered (bit 1 of the first byte), then the
# station address, big-endian (02:00:00:00:03:ea for slave 1002 of that export).
AUTO_MAC_PREFIX = bytes([0x02, 0, 0, 0])


class Errors(Protocol):
    def add(self, message: str, *path: str | int) -> None: ...


def parameters(cfg: Eoe, phys_addr: int) -> IpParameters:
    """The parameters the topology's ``eoe:`` sets (validated by the topology model)."""
    subnet = None
    ip = None
    if cfg.ip is not None:
        interface = ipaddress.IPv4Interface(cfg.ip)
        ip = interface.ip
        if "/" in cfg.ip:
            subnet = interface.netmask
    if cfg.subnet_mask is not None:
        subnet = ipaddress.IPv4Address(cfg.subnet_mask)
    mac = None
    if cfg.mac == MAC_AUTO:
        mac = AUTO_MAC_PREFIX + struct.pack(">H", phys_addr)
    elif cfg.mac is not None:
        mac = bytes.fromhex(cfg.mac.replace(":", "").replace("-", ""))
    return IpParameters(
        mac=mac, ip=ip, subnet_mask=subnet,
        default_gateway=None if cfg.gateway is None else ipaddress.IPv4Address(cfg.gateway),
        dns_server=None if cfg.dns is None else ipaddress.IPv4Address(cfg.dns),
        dns_name=cfg.dns_name)


def init_cmds(name: str, device: Device, phys_addr: int, cfg: Eoe | None,
              slave: tuple[str | int, ...], errors: Errors) -> list[EoeInitCmd]:
    """The EoE InitCmds of one slave (none without ``eoe:``); problems go to ``errors``,
    at ``slave`` (the slave's place in the topology) and its keys."""
    mailbox = device.mailbox
    esi_cmds = mailbox.eoe.init_cmds if mailbox and mailbox.eoe else []
    if esi_cmds:
        # ETG.2000 gives EoE InitCmds a Type and Data whose encoding no public source
        # describes; sending none would lose what the device's own file asks for.
        errors.add(f"slave {name!r}: the ESI of {device.type_name} has EoE InitCmds ("
                   + ", ".join(map(str, esi_cmds)) + "), which ecatcfg does not implement "
                   "and would not send", *slave, "device")
    if cfg is None:
        return []
    where = (*slave, "eoe")
    if mailbox is None or "EoE" not in mailbox.protocols:
        errors.add(f"slave {name!r}: {device.type_name} has no EoE mailbox (its ESI, "
                   f"{device.source}, lists {_protocols(device)}), so IP parameters cannot "
                   "be set", *where)
        return []
    params = parameters(cfg, phys_addr)
    settings = mailbox.eoe
    if params.sets_ip and settings is not None and settings.ip is False:
        errors.add(f"slave {name!r}: the ESI of {device.type_name} says its EoE has no IP "
                   f"support (EoE IP=\"false\", {settings.source}); only 'mac' can be set",
                   *where)
        return []
    data = encode_set_ip_request(params)
    sm0 = next((sm for sm in device.sms if sm.is_mailbox), None)
    if sm0 is not None and sm0.mailbox_size < MAILBOX_HEADER_SIZE + len(data):
        errors.add(f"slave {name!r}: its mailbox (SM0, {sm0.mailbox_size} bytes) cannot "
                   f"carry the EoE request ({MAILBOX_HEADER_SIZE + len(data)} bytes)", *where)
        return []
    return [EoeInitCmd([Transition.IP], COMMENT, data, fixed=True)]


def _protocols(device: Device) -> str:
    protocols = device.mailbox.protocols if device.mailbox else []
    return ", ".join(protocols) if protocols else "no mailbox protocol"
