"""Programming a slave's SII EEPROM: ``ecatcfg sii read|write`` and ``ecatcfg alias set``
against the virtual segment over veth, checked by SOEM (pysoem), a master nobody here wrote,
reading the EEPROM with its own reader, and by ``sii_reference.py``, an SII parser of its
own; and the emulated EEPROM's register behaviour, from ESC Section II (0x0502).

The segment runs with the timing model (``Timing()``): every EEPROM read is busy for
EEPROM_READ_MS and the EEPROM refuses commands for EEPROM_WRITE_MS after each word written,
as real I2C EEPROMs do during their write cycle.
"""

from __future__ import annotations

import json
import re
import struct
import sys
from pathlib import Path

import pytest
import sii_reference as ref
from rig import serving

from ecatcfg.esc import Cmd
from ecatcfg.esi.library import Library
from ecatcfg.runtime import wire
from ecatcfg.runtime.segment.emulate import SlaveSpec, segment
from ecatcfg.runtime.segment.virtual import VirtualSegment
from ecatcfg.runtime.segment.timing import Timing

ROOT = Path(__file__).resolve().parent.parent
ESI = ROOT / "examples" / "esi"
PROBE = Path(__file__).with_name("soem_probe.py")
COUPLER, DRIVE = "EX1100", "EXD-402"


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library([ESI], cache=False)


def line(lib: Library, timing: Timing | None = None) -> VirtualSegment:
    return segment([SlaveSpec(lib.device(lib.find(s).entry), name, serial=7 + i)
                    for i, (s, name) in enumerate([(COUPLER, "coupler"), (DRIVE, "drive")])],
                   timing=timing if timing is not None else Timing())


def ecatcfg(rig, *args: str, cwd: Path) -> tuple[int, str, str]:
    """The command line in the master's namespace, from this checkout."""
    done = rig.run_in(rig.ns_a, [sys.executable, "-m", "ecatcfg", *args], cwd=cwd,
                      timeout=120)
    return done.returncode, done.stdout, done.stderr


def soem_sii(rig, words: int) -> dict:
    done = rig.run_in(rig.ns_a, [sys.executable, str(PROBE), rig.if_a,
                                 json.dumps({"sii_words": words})], timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def with_crc(image: bytes) -> bytes:
    """Word 7's low byte set to the reference's CRC-8 of words 0-6."""
    return image[:14] + bytes([ref.crc8(image[:14])]) + image[15:]


def backup_of(out: str) -> Path:
    found = re.search(r"^backup: (\S+) \(", out, re.M)
    assert found, out
    return Path(found.group(1))


# -- the command line over veth, SOEM as the reference ---------------------------------------

def test_sii_read_gives_the_emulated_image(veth_netns, lib, tmp_path):
    seg = line(lib)
    with serving(veth_netns, seg):
        code, out, err = ecatcfg(veth_netns, "sii", "read", "--iface", veth_netns.if_a,
                                 "--slave", "1", "-o", "drive.bin", cwd=tmp_path)
    assert code == 0, err
    data = (tmp_path / "drive.bin").read_bytes()
    assert data == bytes(seg.slaves[1].eeprom)
    img = ref.parse(data)
    dev = seg.slaves[1].device
    assert (img["vendor_id"], img["product_code"], img["revision"], img["serial"]) == \
        (dev.vendor.id, dev.product_code, dev.revision, 8)
    assert len(data) == img["size_bytes"]                # the whole EEPROM, as word 0x3E says
    assert "drive.bin" in out and f"product 0x{dev.product_code:x}" in out


def test_sii_write_a_changed_image_backs_up_fixes_the_checksum_and_verifies(
        veth_netns, pysoem_module, lib, tmp_path):
    seg = line(lib)
    before = bytes(seg.slaves[1].eeprom)
    name = ref.string(ref.parse(before), 1)
    assert name
    # A new first string of the same length, alias 0x0BAD, and word 7 left as it was: the
    # checksum is now wrong, and the command must fix it.
    image = bytearray(before)
    at = image.index(name.encode())
    image[at:at + len(name)] = ("Z" * len(name)).encode()
    struct.pack_into("<H", image, 8, 0x0BAD)
    (tmp_path / "new.bin").write_bytes(image)
    assert ref.crc8(bytes(image[:14])) != image[14]
    with serving(veth_netns, seg):
        code, out, err = ecatcfg(veth_netns, "sii", "write", "--iface", veth_netns.if_a,
                                 "--slave", "1", "new.bin", cwd=tmp_path)
        assert code == 0, out + err
        report = soem_sii(veth_netns, len(image) // 2)
        seg.power_cycle(1)
        after_power = soem_sii(veth_netns, 8)
    want = with_crc(bytes(image))
    assert bytes(seg.slaves[1].eeprom) == want
    assert (tmp_path / backup_of(out)).read_bytes() == before
    assert "checksum: word 7 said" in out and "fixed" in out and "verified" in out
    # SOEM reads the rewritten EEPROM word for word, and its string.
    assert bytes.fromhex(report["sii"][1]) == want
    assert ref.string(ref.parse(bytes.fromhex(report["sii"][1])), 1) == "Z" * len(name)
    assert report["alias"][1] == 0                       # 0x0012: loaded at power-on only
    assert after_power["alias"][1] == 0x0BAD
    # Only the words that differ were written: the string's, word 4 and word 7.
    written = int(re.search(r"wrote (\d+) of", out).group(1))
    assert written == sum(before[i:i + 2] != want[i:i + 2] for i in range(0, len(want), 2))


def test_an_image_of_another_device_is_refused_without_force(veth_netns, pysoem_module, lib,
                                                              tmp_path):
    seg = line(lib)
    coupler, drive = bytes(seg.slaves[0].eeprom), bytes(seg.slaves[1].eeprom)
    (tmp_path / "coupler.bin").write_bytes(coupler)
    with serving(veth_netns, seg):
        code, out, err = ecatcfg(veth_netns, "sii", "write", "--iface", veth_netns.if_a,
                                 "--slave", "1", "coupler.bin", cwd=tmp_path)
        assert code == 1 and "nothing written" in err and "--force" in err, out + err
        assert bytes(seg.slaves[1].eeprom) == drive
        assert "Traceback" not in err
        code, out, err = ecatcfg(veth_netns, "sii", "write", "--iface", veth_netns.if_a,
                                 "--slave", "1", "coupler.bin", "--force", cwd=tmp_path)
        assert code == 0, out + err
        seg.power_cycle(1)
        report = soem_sii(veth_netns, 8)
    assert bytes(seg.slaves[1].eeprom) == coupler
    dev = seg.slaves[0].device
    assert report["slaves"][1] == {"name": report["slaves"][1]["name"], "vendor": dev.vendor.id,
                                   "product": dev.product_code, "revision": dev.revision}


def test_an_interrupted_write_names_the_words_written_and_the_backup(veth_netns, lib,
                                                                     tmp_path):
    seg = line(lib)
    drive = seg.slaves[1]
    before = bytes(drive.eeprom)
    # A new serial number (words 0x0E-0x0F) and a new first string: more than 3 words.
    image = bytearray(before)
    struct.pack_into("<I", image, 0x1C, 0x12345678)
    name = ref.string(ref.parse(before), 1)
    assert name
    at = image.index(name.encode())
    image[at:at + len(name)] = ("Q" * len(name)).encode()
    (tmp_path / "new.bin").write_bytes(image)
    differ = [w for w in range(len(image) // 2)
              if image[2 * w:2 * w + 2] != before[2 * w:2 * w + 2]]
    assert len(differ) > 3 and differ[:2] == [0x0E, 0x0F]
    words: list[int] = []
    original = drive._eeprom_command

    def pull_the_cable_after_three() -> None:
        was = bytes(drive.eeprom)
        original()
        if bytes(drive.eeprom) != was:
            words.append(1)
            if len(words) == 3:
                seg.remove_cable(drive)       # the slave stops answering mid-way
    drive._eeprom_command = pull_the_cable_after_three        # type: ignore[method-assign]
    with serving(veth_netns, seg):
        code, out, err = ecatcfg(veth_netns, "sii", "write", "--iface", veth_netns.if_a,
                                 "--slave", "1", "new.bin", cwd=tmp_path)
        assert code == 1, out + err
        # The third word went in, but its status never came back: not counted as written.
        assert "2 word(s) written (0x000E-0x000F)" in err, err
        assert f"word 0x{differ[2]:04X} may or may not be written" in err, err
        backup = backup_of(out)
        assert f"--force {backup}" in err and "Traceback" not in err
        now = bytes(drive.eeprom)
        assert [w for w in range(len(now) // 2)
                if now[2 * w:2 * w + 2] != before[2 * w:2 * w + 2]] == differ[:3]
        # The restore the message gives brings the old image back.
        seg.restore_cable(drive)
        drive._eeprom_command = original                      # type: ignore[method-assign]
        command = err[err.index("'ecatcfg ") + 1:].split("'")[0].split()[1:]
        code, out, err = ecatcfg(veth_netns, *command, cwd=tmp_path)
    assert code == 0, out + err
    assert bytes(drive.eeprom) == before


def test_alias_set_then_soem_sees_it_after_a_power_cycle(veth_netns, pysoem_module, lib,
                                                         tmp_path):
    seg = line(lib)
    before = bytes(seg.slaves[0].eeprom)
    with serving(veth_netns, seg):
        code, out, err = ecatcfg(veth_netns, "alias", "set", "--iface", veth_netns.if_a,
                                 "--slave", "0", "4660", cwd=tmp_path)
        assert code == 0, out + err
        first = soem_sii(veth_netns, 64)
        seg.power_cycle(0)
        second = soem_sii(veth_netns, 8)
    assert "power" in out and "wrote 2 of" in out and "verified" in out
    assert (tmp_path / backup_of(out)).read_bytes() == before
    sii = bytes.fromhex(first["sii"][0])
    assert ref.parse(sii)["alias"] == 4660 and sii[14] == ref.crc8(sii[:14])
    assert first["alias"][0] == 0 and second["alias"][0] == 4660
    assert bytes(seg.slaves[0].eeprom) == with_crc(before[:8] + struct.pack("<H", 4660)
                                                   + before[10:])


def test_a_slave_that_is_not_there_is_an_input_error(veth_netns, lib, tmp_path):
    with serving(veth_netns, line(lib)):
        code, out, err = ecatcfg(veth_netns, "alias", "set", "--iface", veth_netns.if_a,
                                 "--slave", "5", "1", cwd=tmp_path)
    assert code == 1 and "no slave at position 5: 2 slave(s) answer" in err, err


# -- the emulated EEPROM's registers (ESC Section II 0x0500-0x050F) -------------------------

class SimClock:
    def __init__(self) -> None:
        self.t = 1_000_000_000

    def __call__(self) -> int:
        return self.t


def send(seg: VirtualSegment, *datagrams: wire.Datagram) -> list[wire.Datagram]:
    return list(wire.decode(seg.process(wire.encode(list(datagrams)))).datagrams)


def control(seg: VirtualSegment, data: bytes) -> int:
    send(seg, wire.Datagram.physical(Cmd.APWR, 0, 0x0502, data))
    got, = send(seg, wire.Datagram.physical(Cmd.APRD, 0, 0x0502, 2))
    value: int = struct.unpack("<H", got.data)[0]
    return value


def test_emulated_eeprom_write_needs_write_enable_and_refuses_during_the_write_cycle(lib):
    clock = SimClock()
    seg = segment([SlaveSpec(lib.device(lib.find(COUPLER).entry), "c")], clock_ns=clock,
                  timing=Timing())
    slave = seg.slaves[0]
    before = bytes(slave.eeprom)
    # Write command (0x0200) without write enable (bit 0): bit 14, nothing written.
    status = control(seg, struct.pack("<HIH", 0x0200, 0x40, 0xBEEF))
    assert status & 0x4000 and not status & 0x8000
    assert bytes(slave.eeprom) == before
    # With write enable: written; a command in the next 3.5 ms is not acknowledged (bit 13)
    # and does nothing; after it, the EEPROM takes commands again.
    assert control(seg, struct.pack("<HIH", 0x0201, 0x40, 0xBEEF)) & 0xF800 == 0
    assert slave.eeprom[0x80:0x82] == b"\xef\xbe"
    clock.t += 3_000_000
    assert control(seg, struct.pack("<HIH", 0x0201, 0x41, 0x1234)) & 0x2000
    assert slave.eeprom[0x82:0x84] == before[0x82:0x84]
    clock.t += 1_000_000
    assert control(seg, struct.pack("<HIH", 0x0201, 0x41, 0x1234)) & 0xF800 == 0
    assert slave.eeprom[0x82:0x84] == b"\x34\x12"


def test_a_power_cycle_resets_the_registers_and_keeps_the_eeprom(lib):
    seg = line(lib)
    slave = seg.slaves[1]
    send(seg, wire.Datagram.physical(Cmd.APWR, 0xFFFF, 0x0010, b"\x02\x10"))   # address
    struct.pack_into("<H", slave.eeprom, 8, 0x0077)                 # alias in the EEPROM
    assert slave.alias == 0
    seg.power_cycle("drive")
    assert slave.alias == 0x0077
    assert struct.unpack_from("<H", slave.mem, 0x0010)[0] == 0          # address reset
    assert struct.unpack_from("<H", slave.eeprom, 8)[0] == 0x0077
    assert [s.position for s in seg.slaves] == [0, 1]
    got, = send(seg, wire.Datagram.physical(Cmd.APRD, 0xFFFF, 0x0130, 2))
    assert got.wkc == 1 and got.data[0] & 0x0F == 1                     # INIT
