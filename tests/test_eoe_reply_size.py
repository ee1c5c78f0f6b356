"""A get IP parameter response that fills the slave's SM1 exactly is sent; one byte more
and the slave answers unspecified error instead, on the request's port
(runtime/segment/eoe_server.py: SM1's length bounds a response, ETG.1000.6 §5.7)."""

from __future__ import annotations

import struct
from ipaddress import IPv4Address

from ecatcfg import eoe
from ecatcfg.esc import AlState
from ecatcfg.runtime.segment.eoe_server import EoeServer

# Mailbox header (ETG.1000.4: length, address, channel/priority, type/counter) + EoE
# header (frame info 1 and 2) + the IP flags (ETG.1000.6 set IP parameter) + the address.
MAILBOX_HEADER, EOE_HEADER, FLAGS, IP = 6, 4, 4, 4
REPLY = MAILBOX_HEADER + EOE_HEADER + FLAGS + IP
PORT = 3


def _get_ip_reply(mbx_in_size: int) -> tuple[int, eoe.EoeFrame]:
    server = EoeServer(None, mbx_in_size)
    # EoE header of a set IP request on port PORT (frame info 1: type 2, port in bits 4-7).
    request = struct.pack("<HH", 2 | PORT << 4, 0) + struct.pack("<I", 0x2) + \
        IPv4Address("10.0.0.7").packed[::-1]
    [done] = server.handle(request, AlState.PREOP)
    assert eoe.decode_frame(done[MAILBOX_HEADER:]).info2 == 0
    [reply] = server.handle(struct.pack("<HH", 6 | PORT << 4, 0), AlState.PREOP)
    return len(reply), eoe.decode_frame(reply[MAILBOX_HEADER:])


def test_a_response_that_fills_sm1_exactly_is_sent():
    size, frame = _get_ip_reply(REPLY)
    assert size == REPLY
    assert (frame.type, frame.port, frame.info2) == (7, PORT, 0)
    assert frame.body == struct.pack("<I", 0x2) + IPv4Address("10.0.0.7").packed[::-1]


def test_a_response_one_byte_too_long_is_unspecified_error_on_its_port():
    size, frame = _get_ip_reply(REPLY - 1)
    assert size == MAILBOX_HEADER + EOE_HEADER
    assert (frame.type, frame.port, frame.info2, frame.body) == (7, PORT, 0x0001, b"")
