"""An SII EEPROM image read straight from its bytes, for the tests: an independent decoder
that shares nothing with ``ecatcfg.esi.sii``.

Layout after ETG.2010 (EtherCAT Slave Information), as SOEM reads it (``ethercatconfig.c``,
``ethercattype.h`` ``ECT_SII_*``) and IgH writes it down (``master/slave.c``): 64 header
words, then categories from word 0x40, each a type word, a length word (in words) and its
data, up to type 0xFFFF.  Multi-byte values are little-endian.
"""

from __future__ import annotations

from typing import Any


def u16(data: bytes, at: int) -> int:
    return data[at] | data[at + 1] << 8


def i16(data: bytes, at: int) -> int:
    value = u16(data, at)
    return value - 0x10000 if value & 0x8000 else value


def u32(data: bytes, at: int) -> int:
    return u16(data, at) | u16(data, at + 2) << 16


def word(data: bytes, n: int) -> int:
    return u16(data, 2 * n)


def parse(data: bytes) -> dict:
    """The header fields and categories of an image, as plain values."""
    img: dict = {
        "pdi_control": word(data, 0x00), "alias": word(data, 0x04),
        "checksum": data[0x0E],
        "vendor_id": u32(data, 0x10), "product_code": u32(data, 0x14),
        "revision": u32(data, 0x18), "serial": u32(data, 0x1C),
        "bootstrap_rx": (word(data, 0x14), word(data, 0x15)),
        "bootstrap_tx": (word(data, 0x16), word(data, 0x17)),
        "std_rx": (word(data, 0x18), word(data, 0x19)),
        "std_tx": (word(data, 0x1A), word(data, 0x1B)),
        "protocols": word(data, 0x1C),
        "size_bytes": (word(data, 0x3E) + 1) * 128, "version": word(data, 0x3F),
        "categories": [], "strings": [], "general": None, "fmmus": [], "syncms": [],
        "txpdos": [], "rxpdos": [], "dc": [],
    }
    at = 0x80
    while at + 4 <= len(data):
        kind, words = u16(data, at), u16(data, at + 2)
        if kind == 0xFFFF:
            break
        body = data[at + 4:at + 4 + 2 * words]
        img["categories"].append(kind)
        _category(img, kind, body)
        at += 4 + 2 * words
    img["end"] = at
    return img


def _category(img: dict, kind: int, body: bytes) -> None:
    if kind == 10:                                      # STRINGS
        at, strings = 1, []
        for _ in range(body[0]):
            n = body[at]
            strings.append(body[at + 1:at + 1 + n].decode("latin-1"))
            at += 1 + n
        img["strings"] = strings
    elif kind == 30:                                    # GENERAL
        img["general"] = {
            "group": body[0], "image": body[1], "order": body[2], "name": body[3],
            "coe_details": body[5], "foe_details": body[6], "eoe_details": body[7],
            "soe_channels": body[8], "flags": body[11], "ebus_current": i16(body, 12),
            "physical_ports": u16(body, 16)}
    elif kind == 40:                                    # FMMU: one usage byte each
        img["fmmus"] = [b for b in body if b != 0xFF]
    elif kind == 41:                                    # SYNCM: 8 bytes each
        img["syncms"] = [(u16(body, i), u16(body, i + 2), body[i + 4], body[i + 6],
                          body[i + 7]) for i in range(0, len(body) - 7, 8)]
    elif kind in (50, 51):                              # TXPDO / RXPDO
        pdos = img["txpdos" if kind == 50 else "rxpdos"]
        at = 0
        while at + 8 <= len(body):
            n = body[at + 2]
            pdo: dict[str, Any] = {"index": u16(body, at), "sm": body[at + 3], "name": body[at + 5],
                   "flags": u16(body, at + 6), "entries": []}
            at += 8
            for _ in range(n):
                pdo["entries"].append({"index": u16(body, at), "subindex": body[at + 2],
                                       "name": body[at + 3], "data_type": body[at + 4],
                                       "bit_len": body[at + 5]})
                at += 8
            pdos.append(pdo)
    elif kind == 60:                                    # DC: 24 bytes per op mode
        img["dc"] = [{"cycle_time0": u32(body, i), "shift_time0": u32(body, i + 4),
                      "shift_time1": u32(body, i + 8), "sync1_factor": i16(body, i + 12),
                      "assign_activate": u16(body, i + 14), "sync0_factor": i16(body, i + 16),
                      "name": body[i + 18], "desc": body[i + 19]}
                     for i in range(0, len(body) - 23, 24)]


def string(img: dict, index: int) -> str | None:
    """String ``index`` of the STRINGS category (1-based; 0, or an index past the list as
    in the SOES XMC4300 image, names none)."""
    return img["strings"][index - 1] if 0 < index <= len(img["strings"]) else None


def crc8(data: bytes) -> int:
    """The config-area checksum (ETG.2010: CRC-8, polynomial x^8 + x^2 + x + 1, initial
    value 0xFF), bit by bit."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc << 1 ^ 0x07) & 0xFF if crc & 0x80 else crc << 1 & 0xFF
    return crc


# -- what an image built from an ESI device holds ---------------------------------------------
# Read from the ESI's XML directly (lxml, no ecatcfg): ETG.2000 elements, ETG.2010 codes.

SM_TYPES = {"MBoxOut": 1, "MBoxIn": 2, "Outputs": 3, "Inputs": 4}       # ETG.2010 SyncM
FMMU_USAGE = {"Outputs": 1, "Inputs": 2, "MBoxState": 3}               # ETG.2010 FMMU
PROTOCOLS = {"AoE": 0x01, "EoE": 0x02, "CoE": 0x04, "FoE": 0x08, "SoE": 0x10, "VoE": 0x20}
PORTS = {"Y": 1, "K": 3}          # Physics letter -> GENERAL port nibble: MII, EBUS
# CoE data type codes (ETG.1000.6 data type table; SOEM ethercattype.h ec_datatype).  BYTE
# and WORD as real images write them: the NI 9144 image WORD as 0x06, the EL2262 image
# BYTE as 0x05 (the CoE codes 0x1E/0x1F are not used there).
COE_TYPES = {"BOOL": 0x01, "SINT": 0x02, "INT": 0x03, "DINT": 0x04, "USINT": 0x05,
             "UINT": 0x06, "UDINT": 0x07, "INT24": 0x10, "ULINT": 0x1B, "BITARR8": 0x2D,
             "BIT2": 0x31, "BYTE": 0x05, "WORD": 0x06}


def number(text: str | None, default: int = 0) -> int:
    """ETG.2000 HexDecValue: ``#x`` hex, else decimal (``default`` when absent or empty)."""
    if text is None or not text.strip():
        return default
    text = text.strip()
    return int(text[2:], 16) if text[:2].lower() == "#x" else int(text)


def flag(el, name: str) -> bool:
    return (el.get(name) or "").strip() in ("1", "true")


def text(el, path: str) -> str | None:
    found = el.find(path)
    return found.text.strip() if found is not None and found.text else None


def english(el, tag: str = "Name") -> str | None:
    """The element's ``tag`` text in English (LcId 1033 or none), else the first one."""
    names = el.findall(tag)
    for n in names:
        if n.get("LcId") in (None, "1033"):
            return (n.text or "").strip()
    return (names[0].text or "").strip() if names else None


def from_esi(device: Any, vendor_id: int) -> dict:
    """What ETG.2010 puts in the image of ESI ``Device`` element ``device``."""
    sms = device.findall("Sm")
    mailbox = device.find("Mailbox")

    def first_mailbox(kind: str) -> tuple[int, int]:
        sm = next((s for s in sms if (s.text or "").strip() == kind), None)
        if sm is None:
            return 0, 0
        assert sm.get("DefaultSize") is not None, f"line {sm.sourceline}: no DefaultSize"
        return number(sm.get("StartAddress"), 0), number(sm.get("DefaultSize"))

    def pdos(tag: str) -> list[dict]:
        out = []
        for p in device.findall(tag):
            if p.get("Sm") is None or flag(p, "Virtual"):
                continue                 # not in the default assignment
            entries = []
            for e in p.findall("Entry"):
                index = number(text(e, "Index"), 0)
                dtype = text(e, "DataType")
                entries.append({"index": index, "subindex": number(text(e, "SubIndex"), 0),
                                "bit_len": number(text(e, "BitLen"), 0),
                                "data_type": COE_TYPES[dtype or ""] if index else 0,
                                "name": english(e) or None if index else None})
            out.append({"index": number(text(p, "Index")), "sm": number(p.get("Sm")),
                        "flags": (0x0001 if flag(p, "Mandatory") else 0)
                        | (0x0010 if flag(p, "Fixed") else 0),
                        "name": english(p) or None, "entries": entries})
        return out

    modes = device.findall("Dc/OpMode")
    current = [m for m in modes if m.find("VendorSpecific/TwinCAT[@IgnoreFromBuildNo]") is None]
    chosen: dict[str | None, Any] = {}
    for m in current or modes:
        chosen.setdefault(text(m, "Name"), m)
    coe = mailbox.find("CoE") if mailbox is not None else None
    coe_details = 0
    if coe is not None:
        coe_details = 0x01
        for attr, bit in (("SdoInfo", 0x02), ("PdoAssign", 0x04), ("PdoConfig", 0x08),
                          ("PdoUpload", 0x10), ("CompleteAccess", 0x20)):
            coe_details |= bit if flag(coe, attr) else 0
    physics = device.get("Physics") or ""
    ebus = number(text(device, "Info/Electrical/EBusCurrent"), 0)
    return {
        "identity": (vendor_id, number(device.find("Type").get("ProductCode")),
                     number(device.find("Type").get("RevisionNo"))),
        "std_rx": first_mailbox("MBoxOut"), "std_tx": first_mailbox("MBoxIn"),
        "protocols": sum(bit for name, bit in PROTOCOLS.items()
                         if mailbox is not None and mailbox.find(name) is not None),
        "syncms": [(number(s.get("StartAddress"), 0), number(s.get("DefaultSize"), 0),
                    number(s.get("ControlByte"), 0),
                    (0x01 if flag(s, "Enable") else 0) | (0x04 if flag(s, "Virtual") else 0)
                    | (0x08 if flag(s, "OpOnly") else 0),
                    SM_TYPES.get((s.text or "").strip(), 0)) for s in sms],
        "fmmus": [FMMU_USAGE.get((f.text or "").strip(), 0) for f in device.findall("Fmmu")],
        "txpdos": pdos("TxPdo"), "rxpdos": pdos("RxPdo"),
        "dc": [{"assign_activate": number(text(m, "AssignActivate"), 0),
                "shift_time0": number(text(m, "ShiftTimeSync0"), 0),
                "shift_time1": number(text(m, "ShiftTimeSync1"), 0)}
               for m in chosen.values()],
        "order": text(device, "Type"), "group": text(device, "GroupType"),
        "name": english(device) or text(device, "Type"),
        "coe_details": coe_details,
        "foe_details": int(mailbox is not None and mailbox.find("FoE") is not None),
        "eoe_details": int(mailbox is not None and mailbox.find("EoE") is not None),
        "ebus_current": max(-0x8000, min(0x7FFF, ebus)),
        "physical_ports": sum(PORTS.get(letter.upper(), 0) << 4 * port
                              for port, letter in enumerate(physics[:4])),
    }
