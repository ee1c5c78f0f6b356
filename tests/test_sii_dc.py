"""The SII DC category (ETG.2010, 24 bytes per op mode) we build from an ESI against the
real EEPROM images of the corpus, byte for byte.

The real images: two NI 9144 chassis (their ESI's ``DcOff`` mode has no
``CycleTimeSync0``; ``DcSync`` has ``CycleTimeSync0 Factor="1"``) and an EL2262 (negative
factors, SYNC1).  Each mode's bytes must be equal except the name's string index (+0x12):
where a name sits in the string table is each image's own choice, so the name is compared
as text instead.  The description index (+0x13) is 0 in all three real images.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ecatcfg.esi import sii
from ecatcfg.esi.library import Library

MODE = 24
NAME_INDEX = 0x12

PAIRS = [("io/NI9144.xml", "ni9144/ni_9144_rev_1.bin"),
         ("io/NI9144.xml", "ni9144/ni_9144_rev_2.bin"),
         ("beckhoff/Beckhoff EL2xxx.xml", "ethercrab-dumps/el2262.bin")]


def dc_body(image: bytes) -> tuple[sii.SiiImage, bytes]:
    img = sii.decode(image)
    [cat] = [c for c in img.categories if c.type == sii.CAT_DC]
    return img, image[cat.offset + 4:cat.offset + 4 + cat.size]


@pytest.mark.parametrize("esi,dump", PAIRS, ids=[p[1] for p in PAIRS])
def test_dc_category_equals_the_real_image(corpus: Path, esi: str, dump: str):
    raw = (corpus / "sii" / dump).read_bytes()
    real, theirs = dc_body(raw)
    lib = Library([corpus / "esi" / esi], cache=False)
    dev = lib.device(f"{real.vendor_id:#x}:{real.product_code:#x}:{real.revision:#x}")
    ours_img, ours = dc_body(sii.build(dev, serial=real.serial, alias=real.alias))
    assert len(ours) == len(theirs) and len(theirs) % MODE == 0 and theirs
    for n in range(len(theirs) // MODE):
        a = bytearray(ours[n * MODE:(n + 1) * MODE])
        b = bytearray(theirs[n * MODE:(n + 1) * MODE])
        assert ours_img.string(a[NAME_INDEX]) == real.string(b[NAME_INDEX])
        a[NAME_INDEX] = b[NAME_INDEX] = 0
        assert a.hex(" ") == b.hex(" "), f"mode {n} ({real.dc[n].name})"


def test_a_mode_without_cycle_time_sync0_has_sync0_factor_1(corpus: Path):
    """The NI 9144's DcOff: no CycleTimeSync0 in the ESI, SYNC0 factor 1 (+0x10) in both
    real images (not 0), and in ours."""
    lib = Library([corpus / "esi" / "io/NI9144.xml"], cache=False)
    for dump in ("ni9144/ni_9144_rev_1.bin", "ni9144/ni_9144_rev_2.bin"):
        real, body = dc_body((corpus / "sii" / dump).read_bytes())
        dev = lib.device(f"{real.vendor_id:#x}:{real.product_code:#x}:{real.revision:#x}")
        assert dev.dc is not None and dev.dc.opmodes[0].name == "DcOff"
        assert dev.dc.opmodes[0].cycle_time_sync0 is None
        _, ours = dc_body(sii.build(dev))
        assert real.dc[0].name == "DcOff" and body[0x10:0x12] == ours[0x10:0x12] == b"\x01\x00"
