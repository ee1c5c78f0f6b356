"""EoE (Ethernet over EtherCAT, ETG.1000.6 §5.7): the EoE header and the "set IP parameter"
request and response, as ENI files and the wire carry them.

One codec for three users, the way ``esc.py`` serves compiler and runtime: the ENI reader
checks an EoE InitCmd's ``Data`` with :func:`decode_init_data`, the master sends
:func:`encode_set_ip_request` in a mailbox of type EoE, and the emulated slave decodes that
request with :func:`decode_frame` and :func:`decode_ip_parameters` and answers with
:func:`encode_set_ip_response` (or :func:`encode_get_ip_response`, :func:`encode_response`).
The layouts, with the projects where each can be checked, are in
``docs/protocol-notes.md`` §9.

- **EoE header**, 4 bytes after the mailbox header: frame info 1 (type in bits 0-3, port
  4-7, last fragment 8, time appended 9, time requested 10) and frame info 2 (fragment,
  offset and frame numbers; in a response, the result code).
- **Set IP parameter body**: a 32-bit flags word (bit 0 MAC, 1 IP address, 2 subnet mask,
  3 default gateway, 4 DNS server, 5 DNS name) and the parameters.  IgH and the ENI files
  write every field at a fixed place, 58 bytes in all (zeros where a flag is clear;
  Wireshark dissects it that way, and IgH notes that TwinCAT 2.1 ignores the fields after
  a missing one); SOEM 1.x writes only the fields whose flag is set, and SOES answers a get
  IP parameter request that way.
  :func:`decode_ip_parameters` reads both, :func:`encode_ip_parameters` writes either (the
  fixed one unless told otherwise).  An IPv4 address is a 32-bit little-endian number:
  192.168.1.4 is ``04 01 a8 c0`` (SOEM ``EOE_ip_uint32_to_byte``; the ENI files agree).
"""

from __future__ import annotations

import ipaddress
import struct
from enum import IntEnum
from typing import TypeVar

from ecatcfg.record import record

_T = TypeVar("_T")

HEADER = struct.Struct("<HH")             # frame info 1, frame info 2 (or result code)
HEADER_SIZE = HEADER.size                  # 4
TYPE_MASK = 0x000F
PORT_SHIFT = 4
PORT_MASK = 0x00F0
LAST_FRAGMENT = 0x0100
TIME_APPENDED = 0x0200
TIME_REQUESTED = 0x0400


class FrameType(IntEnum):
    """EoE header frame info 1, bits 0-3 (SOEM ``ethercateoe.h``, Wireshark ``packet-ecatmb``)."""

    FRAGMENT = 0
    TIMESTAMP = 1
    SET_IP_REQUEST = 2
    SET_IP_RESPONSE = 3
    SET_FILTER_REQUEST = 4
    SET_FILTER_RESPONSE = 5
    GET_IP_REQUEST = 6
    GET_IP_RESPONSE = 7
    GET_FILTER_REQUEST = 8
    GET_FILTER_RESPONSE = 9


class Result(IntEnum):
    """Result code of a response (frame info 2): SOEM ``EOE_RESULT_*``, IgH ``fsm_eoe.c``."""

    SUCCESS = 0x0000
    UNSPECIFIED_ERROR = 0x0001
    UNSUPPORTED_FRAME_TYPE = 0x0002
    NO_IP_SUPPORT = 0x0201
    NO_DHCP_SUPPORT = 0x0202
    NO_FILTER_SUPPORT = 0x0401


RESULT_NAMES: dict[int, str] = {
    Result.SUCCESS: "success", Result.UNSPECIFIED_ERROR: "unspecified error",
    Result.UNSUPPORTED_FRAME_TYPE: "unsupported frame type",
    Result.NO_IP_SUPPORT: "no IP support", Result.NO_DHCP_SUPPORT: "no DHCP support",
    Result.NO_FILTER_SUPPORT: "no address filter support"}


def result_name(code: int) -> str:
    return RESULT_NAMES.get(code, "unknown result code")


# Set IP parameter flags (the body's first 32 bits).
MAC = 0x01
IP = 0x02
SUBNET_MASK = 0x04
DEFAULT_GATEWAY = 0x08
DNS_SERVER = 0x10
DNS_NAME = 0x20
FLAGS = MAC | IP | SUBNET_MASK | DEFAULT_GATEWAY | DNS_SERVER | DNS_NAME
MAC_SIZE = 6
DNS_NAME_SIZE = 32                         # SOEM EOE_DNS_NAME_LENGTH, IgH EC_MAX_HOSTNAME_SIZE
# (flag, size) in body order after the flags word.
_FIELDS = ((MAC, MAC_SIZE), (IP, 4), (SUBNET_MASK, 4), (DEFAULT_GATEWAY, 4), (DNS_SERVER, 4),
           (DNS_NAME, DNS_NAME_SIZE))
FLAGS_SIZE = 4
FIXED_BODY_SIZE = FLAGS_SIZE + sum(size for _, size in _FIELDS)      # 58


@record(frozen=True)
class IpParameters:
    """What a set IP parameter request sets; ``None`` where its flag is clear."""

    mac: bytes | None = None
    ip: ipaddress.IPv4Address | None = None
    subnet_mask: ipaddress.IPv4Address | None = None
    default_gateway: ipaddress.IPv4Address | None = None
    dns_server: ipaddress.IPv4Address | None = None
    dns_name: str | None = None

    @property
    def values(self) -> tuple[object, ...]:
        """The six parameters in body order (the order of ``_FIELDS``)."""
        return (self.mac, self.ip, self.subnet_mask, self.default_gateway, self.dns_server,
                self.dns_name)

    @property
    def flags(self) -> int:
        return sum(flag for (flag, _), value in zip(_FIELDS, self.values) if value is not None)

    @property
    def sets_ip(self) -> bool:
        """Whether it sets anything of the IP stack (address, mask, gateway, DNS), not only
        the MAC address: what a device without IP support must refuse."""
        return any(value is not None for value in self.values[1:])     # all but the MAC

    def updated(self, newer: IpParameters) -> IpParameters:
        """These parameters after ``newer`` is set: its fields where given, ours elsewhere
        (a request sets only the fields its flags name; SOES ``EOE_set_ip``)."""
        def pick(new: _T | None, old: _T | None) -> _T | None:
            return old if new is None else new

        return IpParameters(mac=pick(newer.mac, self.mac), ip=pick(newer.ip, self.ip),
                            subnet_mask=pick(newer.subnet_mask, self.subnet_mask),
                            default_gateway=pick(newer.default_gateway, self.default_gateway),
                            dns_server=pick(newer.dns_server, self.dns_server),
                            dns_name=pick(newer.dns_name, self.dns_name))

    def describe(self) -> str:
        """``ip 192.168.1.4/255.255.255.0, gateway 192.168.1.10, mac 10:18:9e:ff:01:04``."""
        parts = []
        if self.ip is not None:
            parts.append(f"ip {self.ip}" + (f"/{self.subnet_mask}" if self.subnet_mask
                                              is not None else ""))
        elif self.subnet_mask is not None:
            parts.append(f"subnet mask {self.subnet_mask}")
        if self.default_gateway is not None:
            parts.append(f"gateway {self.default_gateway}")
        if self.dns_server is not None:
            parts.append(f"dns {self.dns_server}")
        if self.dns_name is not None:
            parts.append(f"name {self.dns_name!r}")
        if self.mac is not None:
            parts.append("mac " + self.mac.hex(":"))
        return ", ".join(parts) or "nothing"


def _ip_bytes(address: ipaddress.IPv4Address | None) -> bytes:
    return struct.pack("<I", int(address)) if address is not None else bytes(4)


def encode_ip_parameters(params: IpParameters, compact: bool = False) -> bytes:
    """A set (or get) IP parameter body: the fixed 58-byte layout (IgH
    ``ec_fsm_eoe_prepare_set``, the ENI files), or with ``compact`` only the fields whose flag is
    set (SOEM ``ecx_EOEsetIp``, SOES ``EOE_get_ip``)."""
    name = b""
    if params.dns_name is not None:
        name = params.dns_name.encode("ascii")
        if len(name) > DNS_NAME_SIZE:
            raise ValueError(f"DNS name of {len(name)} characters; at most {DNS_NAME_SIZE}")
    raw = (params.mac or bytes(MAC_SIZE), _ip_bytes(params.ip), _ip_bytes(params.subnet_mask),
           _ip_bytes(params.default_gateway), _ip_bytes(params.dns_server),
           name.ljust(DNS_NAME_SIZE, b"\x00"))
    return struct.pack("<I", params.flags) + b"".join(
        field for field, value in zip(raw, params.values) if not compact or value is not None)


def _compact_size(flags: int) -> int:
    return FLAGS_SIZE + sum(size for flag, size in _FIELDS if flags & flag)


def decode_ip_parameters(body: bytes) -> IpParameters:
    """A set IP parameter body in the fixed layout (58 bytes) or with only the fields its
    flags name (SOEM 1.x); ``ValueError`` says what does not fit.  The length must be one
    of the two exactly: that is what tells the ENI encodings apart."""
    if len(body) < FLAGS_SIZE:
        raise ValueError(f"{len(body)} bytes: too short for the set IP parameter flags")
    flags, = struct.unpack_from("<I", body)
    if flags & ~FLAGS:
        raise ValueError(f"flags 0x{flags:08X}: bits other than the six parameters "
                         f"(0x{FLAGS:02X}) are set")
    fixed = len(body) == FIXED_BODY_SIZE
    if not fixed and len(body) != _compact_size(flags):
        raise ValueError(f"{len(body)} bytes: neither the fixed {FIXED_BODY_SIZE}-byte layout "
                         f"nor the {_compact_size(flags)} bytes its flags 0x{flags:02X} name")
    values: list[bytes | None] = []
    offset = FLAGS_SIZE
    for flag, size in _FIELDS:
        if flags & flag:
            values.append(body[offset:offset + size])
        else:
            values.append(None)
        if fixed or flags & flag:
            offset += size
    mac, ip, mask, gateway, dns, name = values

    def address(raw: bytes | None) -> ipaddress.IPv4Address | None:
        return None if raw is None else ipaddress.IPv4Address(struct.unpack("<I", raw)[0])

    dns_name = None
    if name is not None:
        text = name.split(b"\x00", 1)[0]
        try:
            dns_name = text.decode("ascii")
        except UnicodeDecodeError:
            raise ValueError(f"DNS name {text!r} is not ASCII") from None
    return IpParameters(mac=mac, ip=address(ip), subnet_mask=address(mask),
                        default_gateway=address(gateway), dns_server=address(dns),
                        dns_name=dns_name)


# -- frames ---------------------------------------------------------------------------------

@record(frozen=True)
class EoeFrame:
    """An EoE mailbox payload: the header's fields and what follows it."""

    type: int
    port: int
    last_fragment: bool
    info2: int                       # fragment/offset/frame numbers, or a response's result
    body: bytes


def frame_info(frame_type: int, port: int = 0, last_fragment: bool = False) -> int:
    if not 0 <= port <= 15:
        raise ValueError(f"EoE port {port}: 0..15")
    return frame_type | port << PORT_SHIFT | (LAST_FRAGMENT if last_fragment else 0)


def decode_frame(payload: bytes) -> EoeFrame:
    """An EoE mailbox payload (after the mailbox header); ``ValueError`` if too short."""
    if len(payload) < HEADER_SIZE:
        raise ValueError(f"{len(payload)} bytes: too short for the EoE header")
    info1, info2 = HEADER.unpack_from(payload)
    return EoeFrame(type=info1 & TYPE_MASK, port=(info1 & PORT_MASK) >> PORT_SHIFT,
                    last_fragment=bool(info1 & LAST_FRAGMENT), info2=info2,
                    body=payload[HEADER_SIZE:])


def encode_set_ip_request(params: IpParameters, port: int = 0) -> bytes:
    """The EoE payload of a set IP parameter request.  The header is the one IgH sends and
    EC-Engineer writes into its ENI files: type 2, frame info 2 zero, no fragment bit."""
    return HEADER.pack(frame_info(FrameType.SET_IP_REQUEST, port), 0) + \
        encode_ip_parameters(params)


def encode_response(frame_type: int, result: int, port: int = 0, body: bytes = b"") -> bytes:
    """The EoE payload of a response: the last-fragment bit set and the result code in frame
    info 2 (SOES ``EOE_no_data_response``; SOEM ``ecx_EOEsetIp`` and IgH ``fsm_eoe.c`` read
    the result there), then ``body``."""
    return HEADER.pack(frame_info(frame_type, port, last_fragment=True), result) + body


def encode_set_ip_response(result: int, port: int = 0) -> bytes:
    """A set IP parameter response: type 3 with the result code and no body."""
    return encode_response(FrameType.SET_IP_RESPONSE, result, port)


def encode_get_ip_request(port: int = 0) -> bytes:
    """A get IP parameter request: type 6, the EoE header alone (SOEM ``ecx_EOEgetIp``)."""
    return HEADER.pack(frame_info(FrameType.GET_IP_REQUEST, port), 0)


def encode_get_ip_response(params: IpParameters, port: int = 0) -> bytes:
    """A get IP parameter response: type 7, result success, the parameters that are set in
    the compact layout, as SOES ``EOE_get_ip`` answers and SOEM ``ecx_EOEgetIp`` reads it
    (SOEM reads no other layout; with every flag set the two layouts are the same)."""
    return encode_response(FrameType.GET_IP_RESPONSE, Result.SUCCESS, port,
                           encode_ip_parameters(params, compact=True))


# -- what ENI files write ------------------------------------------------------------------

@record(frozen=True)
class SetIpRequest:
    """An ENI EoE InitCmd's ``Data``, decoded."""

    params: IpParameters
    port: int = 0
    with_header: bool = False        # the file wrote the EoE header in front of the body


def decode_init_data(data: bytes) -> SetIpRequest:
    """An EoE InitCmd's ``Data`` as real ENI files write it (``docs/eni-exports.md`` §9):

    - the set IP parameter body alone (Elmo Application Studio): flags first;
    - the EoE header in front of it (EC-Engineer): type 2, frame info 2 zero.

    Either must decode completely; data that reads both ways is refused as ambiguous.
    ``ValueError`` says why neither fits.
    """
    alone: SetIpRequest | None = None
    framed: SetIpRequest | None = None
    problems = []
    try:
        alone = SetIpRequest(decode_ip_parameters(data))
    except ValueError as exc:
        problems.append(f"as a set IP parameter body: {exc}")
    try:
        frame = decode_frame(data)
        if frame.type != FrameType.SET_IP_REQUEST or frame.info2 != 0:
            raise ValueError(f"an EoE header of type {frame.type}, frame info 2 "
                             f"0x{frame.info2:04X} (a set IP parameter request is type 2, 0)")
        framed = SetIpRequest(decode_ip_parameters(frame.body), frame.port, with_header=True)
    except ValueError as exc:
        problems.append(f"with an EoE header: {exc}")
    if alone is not None and framed is not None:
        raise ValueError("reads both as a set IP parameter body and as one with an EoE header "
                         f"({alone.params.describe()} / {framed.params.describe()})")
    found = alone or framed
    if found is None:
        raise ValueError("not a set IP parameter request: " + "; ".join(problems))
    return found
