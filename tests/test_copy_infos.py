"""Slave-to-slave copies (ENI ``Cyclic/Frame/Cmd/CopyInfos``): read, written, applied.

The example line (examples/: self-written ESI files) compiled, with CopyInfos added to its
process-data LRW: input bits of one slave copied to output bits of another.  What the
output slave receives is read from the emulated slave's output SyncManager memory
(``EmulatedSlave.outputs()``), not from the master's image.  Image layout of the example:
inputs byte 0 = buttons (bits 0-3) and sensors (bits 4-7); outputs byte 1 = lamps.
"""

from __future__ import annotations

import copy as copying

import pytest
from lxml import etree

from conftest import EXAMPLES
from ecatcfg.eni import reader as eni_reader
from ecatcfg.eni import writer as eni_writer
from ecatcfg.eni.contents import UnsupportedEniError
from ecatcfg.eni.plan import CopyInfo, Frame, NetworkPlan
from ecatcfg.esc import DATAGRAM_HEADER, AlState, Cmd
from ecatcfg.runtime import Network
from ecatcfg.runtime.network import SkippedConfigWarning

ESI = [EXAMPLES / "esi"]
SENSORS_IN = 4          # input bits 4..7: the sensors' channels 1-4
LAMPS_OUT = 8           # output bits 8..15: the lamps' channels 1-8


def _lrw(plan: NetworkPlan):
    [cmd] = [c for cyc in plan.cyclic for f in cyc.frames for c in f.cmds if c.cmd == Cmd.LRW]
    return cmd


def with_copies(plan: NetworkPlan, *copies: CopyInfo) -> NetworkPlan:
    """``plan`` with ``copies`` on its process-data LRW, written to XML and read back: the
    runtime gets what a file says."""
    plan = copying.deepcopy(plan)
    _lrw(plan).copy_infos = list(copies)
    return eni_reader.read_bytes(eni_writer.to_bytes(plan), "copies.eni.xml")


def sensors(net: Network, bits: int) -> None:
    """The sensors' four channels (slave 2's input SM), as its application sets them."""
    net.segment.slaves[2].set_inputs(bytes([bits]))


def lamps(net: Network) -> int:
    """What the lamps (slave 3) received: its output SyncManager's byte."""
    [value] = net.segment.slaves[3].outputs()
    return value


# -- the plan: read, written, schema-valid ----------------------------------------------------

def test_copy_infos_round_trip_in_schema_order(example_plan, eni_schema):
    plan = with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT + 2, 4),
                       CopyInfo(0, LAMPS_OUT, 8))
    assert _lrw(plan).copy_infos == [CopyInfo(4, 10, 4), CopyInfo(0, 8, 8)]
    assert eni_reader.read_bytes(eni_writer.to_bytes(plan), "again.xml") == plan
    root = etree.fromstring(eni_writer.to_bytes(plan))
    assert eni_schema.validate(root.getroottree()), eni_schema.error_log
    [cmd] = [c for c in root.iterfind(".//Cyclic/Frame/Cmd") if c.find("CopyInfos") is not None]
    assert [e.tag for e in cmd][-3:] == ["InputOffs", "OutputOffs", "CopyInfos"]
    assert plan.unsupported == []


# -- on the virtual segment -------------------------------------------------------------------

def test_input_bits_reach_another_slaves_outputs_one_cycle_later(example_plan):
    """Four sensor bits (input bits 4-7) to lamps 3-6 (output bits 10-13): not byte
    aligned, shifted by a different amount on each side; the lamps' other outputs stay as
    the application writes them."""
    plan = with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT + 2, 4))
    with Network.virtual(plan, ESI, esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        net["lamps.Channel 1-8.Output 1"] = True
        net["lamps.Channel 1-8.Output 8"] = True
        sensors(net, 0b1011)
        assert net.cycle()              # reads the sensors, then copies
        assert lamps(net) & 0b0011_1100 == 0
        assert net.cycle()              # sends the copy
        assert lamps(net) == 0b1010_1101
        sensors(net, 0b0100)
        assert net.cycle() and net.cycle()
        assert lamps(net) == 0b1001_0001


def test_whole_bytes_are_copied_from_two_slaves(example_plan):
    """Input byte 0 (buttons and sensors) to the lamps' byte: the aligned copy."""
    plan = with_copies(example_plan, CopyInfo(0, LAMPS_OUT, 8))
    with Network.virtual(plan, ESI, esi_cache=False) as net:
        net.up()
        net.segment.slaves[1].set_inputs(b"\x05")
        sensors(net, 0b1001)
        assert net.cycle() and net.cycle()
        assert lamps(net) == 0x95


def test_copies_run_in_eni_order(example_plan):
    """Two copies to the same lamps: the later one in the file wins."""
    plan = with_copies(example_plan, CopyInfo(0, LAMPS_OUT, 4),
                       CopyInfo(SENSORS_IN, LAMPS_OUT, 4))
    with Network.virtual(plan, ESI, esi_cache=False) as net:
        net.up()
        net.segment.slaves[1].set_inputs(b"\x0f")
        sensors(net, 0b0010)
        assert net.cycle() and net.cycle()
        assert lamps(net) == 0b0010


def test_a_wrong_working_counter_keeps_the_last_value(example_plan):
    """The drive's cable pulled: the LRW's working counter is 4, not 7, so its input data
    is not valid and the copy is not made; the lamps keep the last copied value though the
    sensors changed.  Back in the line, copies resume."""
    plan = with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT, 4))
    with Network.virtual(plan, ESI, esi_cache=False, recovery=False) as net:
        net.up()
        sensors(net, 0b0110)
        assert net.cycle() and net.cycle()
        assert lamps(net) == 0b0110
        net.segment.remove_cable("axis1")
        sensors(net, 0b1001)
        for _ in range(3):
            assert not net.cycle()
        assert _lrw(plan).cnt == 7 and net.master.cyclic.frames  # the ENI's Cnt
        assert net["sensors.Channel 1.Input"] is True       # read, just not copied
        assert lamps(net) == 0b0110
        net.segment.restore_cable("axis1")
        net.cycle()
        net.cycle()
        assert lamps(net) == 0b1001


def test_copies_in_twincats_frame_shaped_image(example_plan):
    """The same line with TwinCAT's offsets (docs/eni-exports.md §4): each command's
    InputOffs/OutputOffs is its datagram header's place in the Ethernet frame, the data 10
    bytes later, and the variables' BitOffs follow.  CopyInfo offsets count in that same
    image (ETG.2100: "bit offs in the complete process image"): the sensors' bits are at
    input bit 8·(offs + 10) + 4, not 8·offs + 4."""
    plan = copying.deepcopy(example_plan)
    [frame] = [f for cyc in plan.cyclic for f in cyc.frames]
    at = 14 + 2                        # Ethernet header + EtherCAT header
    moved: dict[int, int] = {}
    for cmd in frame.cmds:
        moved[cmd.input_offs] = at     # compact offsets -> frame-shaped ones
        cmd.input_offs = cmd.output_offs = at
        at += DATAGRAM_HEADER + cmd.length + 2
    assert isinstance(frame, Frame) and frame.data_shift == DATAGRAM_HEADER
    lrw = _lrw(plan)
    base = 8 * (lrw.input_offs + DATAGRAM_HEADER)
    image = plan.process_image
    for var in image.inputs + image.outputs:
        var.bit_offs += base
    image.inputs_size = image.outputs_size = 1536
    plan = with_copies(plan, CopyInfo(base + SENSORS_IN, base + LAMPS_OUT + 1, 4))
    assert plan.unsupported == []
    with Network.virtual(plan, ESI, esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        sensors(net, 0b1101)
        assert net.cycle() and net.cycle()
        assert net["sensors.Channel 1.Input"] is True
        assert lamps(net) == 0b1101 << 1


def test_a_copy_outside_the_images_is_refused_by_name(example_plan):
    plan = with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT, 4),
                       CopyInfo(8 * 25 - 2, 0, 4))
    assert _lrw(plan).copy_infos == [CopyInfo(SENSORS_IN, LAMPS_OUT, 4)]
    [part] = plan.unsupported
    assert part.element == "Cyclic/Frame/Cmd/CopyInfos/CopyInfo" and part.line
    assert part.what == ("a slave-to-slave copy outside the process image (copy 4 bits: "
                         "input bit 198 (byte 24.6) -> output bit 0 (byte 0.0); the images "
                         "have 25 input and 25 output bytes)")
    with pytest.raises(UnsupportedEniError, match="outside the process image") as refused:
        Network.virtual(plan, ESI, esi_cache=False)
    assert [p.element for p in refused.value.parts] == ["Cyclic/Frame/Cmd/CopyInfos/CopyInfo"]
    # Skipped, the copy inside the images is still made.
    with pytest.warns(SkippedConfigWarning, match="the master: skipped a slave-to-slave copy "
                      "outside the process image"):
        net = Network.virtual(plan, ESI, esi_cache=False, skip_unsupported=True)
    with net:
        net.up()
        sensors(net, 0b0101)
        assert net.cycle() and net.cycle()
        assert lamps(net) == 0b0101


# -- show, diff, report -----------------------------------------------------------------------

def _file(tmp_path, plan: NetworkPlan, name: str):
    path = tmp_path / name
    path.write_bytes(eni_writer.to_bytes(plan))
    return path


def test_show_names_the_copies_by_their_variables(example_plan, tmp_path):
    from ecatcfg.eni.show import as_json, summary
    plan = with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT + 2, 4),
                       CopyInfo(17, 200 - 8, 8))
    lrw = next(c for f in summary(plan, "x").frames for c in f.commands if c.cmd == "LRW")
    assert lrw.copies == [
        "copy 4 bits: sensors.Channel 1.Input (in 0.4) -> lamps.Channel 1-8.Output 3 (out 1.2)",
        "copy 8 bits: axis1.TxPDO 1 (CSP).Statusword +1 (in 2.1) -> out 24.0"]
    shown = as_json(summary(plan, "x"))
    assert [c["copies"] for f in shown["frames"] for c in f["commands"] if c["copies"]] == [
        lrw.copies]


def test_diff_compares_copies_by_variable_across_image_conventions(example_plan, tmp_path):
    """Moved copies are a change; the same copies in another ENI order are one too (the
    later wins where they overlap)."""
    from ecatcfg.eni.diff import diff
    a = with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT, 4))
    b = with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT + 1, 4))
    [change] = [c for c in diff(a, b) if c.kind == "copies"]
    assert change.old == ("copy 4 bits: sensors.Channel 1.Input (in 0.4) -> "
                          "lamps.Channel 1-8.Output 1 (out 1.0)")
    assert change.new.endswith("-> lamps.Channel 1-8.Output 2 (out 1.1)")
    assert [c for c in diff(a, a) if c.kind == "copies"] == []
    none = [c for c in diff(example_plan, a) if c.kind == "copies"]
    assert [(c.old, c.new) for c in none] == [("none", change.old)]


def test_the_report_page_lists_the_copies(example_plan, tmp_path):
    import subprocess
    import sys
    plan = with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT + 2, 4))
    eni = _file(tmp_path, plan, "copies.eni.xml")
    page = tmp_path / "page.html"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "report", str(eni), "-o",
                           str(page), "--esi", str(EXAMPLES / "esi")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert ("then copy 4 bits: sensors.Channel 1.Input (in 0.4) -&gt; lamps.Channel 1-8."
            "Output 3 (out 1.2)") in page.read_text()


@pytest.mark.parametrize("kind", ["pysoem", "soem-c"])
def test_the_export_refuses_copies_by_file_and_line(example_plan, tmp_path, kind):
    """SOEM's cycle has no place for the copies and gates on the group's working counter,
    not the command's: refused by the CopyInfo's line, nothing written."""
    import subprocess
    import sys
    eni = _file(tmp_path, with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT + 2, 4)),
                "copies.eni.xml")
    [line] = [e.sourceline for e in etree.parse(str(eni)).iterfind(".//CopyInfo")]
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           kind, "-o", str(out), "--no-cache"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 1, done.stderr
    assert done.stderr.startswith(
        f"ecatcfg export: {eni}:{line}: the master: slave-to-slave copies (CopyInfos) are not "
        "exported: copy 4 bits: sensors.Channel 1.Input (in 0.4) -> lamps.Channel 1-8.Output "
        "3 (out 1.2)"), done.stderr
    assert not out.exists()


def test_a_copy_across_byte_boundaries_reaches_two_slaves(example_plan):
    """12 bits from the drive's status word (input bits 18..29: bytes 2 and 3) to output
    bits 12..23: the lamps' channels 5-8 and the low byte of the drive's control word."""
    import struct
    plan = with_copies(example_plan, CopyInfo(18, 12, 12))
    with Network.virtual(plan, ESI, esi_cache=False) as net:
        net.up()
        net["lamps.Channel 1-8.Output 1"] = True
        net["axis1.RxPDO 2 (CSV).Controlword"] = 0x0600
        net.segment.slaves[4].set_inputs(struct.pack("<H", 0xABCD))
        assert net.cycle() and net.cycle()
        value = 0xABCD >> 2 & 0xFFF                                   # 0xAF3
        assert lamps(net) == (value & 0xF) << 4 | 1
        drive = net.segment.slaves[4].outputs()
        assert struct.unpack_from("<H", drive) == (0x0600 | value >> 4,)


def _bits(image: bytes | bytearray, first: int, n: int) -> list[int]:
    return [image[b // 8] >> b % 8 & 1 for b in range(first, first + n)]


def _copy_and_compare(example_plan, copy: CopyInfo, rng) -> None:
    """``copy`` made by the cyclic frames over random images, against the same copy made
    here one bit at a time; the bits around the destination are left as they were."""
    from ecatcfg.runtime.master.cyclic import CyclicFrames
    n = copy.bit_size
    plan = copying.deepcopy(example_plan)
    lrw = _lrw(plan)
    lrw.copy_infos = [copy]
    frames = CyclicFrames(plan)
    frames.inputs[:] = rng.randbytes(len(frames.inputs))
    frames.outputs[:] = before = bytearray(rng.randbytes(len(frames.outputs)))
    for p in frames.prepared(AlState.OP):
        p.bind(frames.inputs, frames.outputs, bytearray(2048))
        for s in p.slots:
            s.wkc = s.cmd.cnt if s.cmd.cnt is not None else 0
        p.copy_slave_to_slave()
    want = bytearray(before)
    for k, bit in enumerate(_bits(frames.inputs, copy.src_bit_offs, n)):
        at = copy.dst_bit_offs + k
        want[at // 8] = want[at // 8] & ~(1 << at % 8) | bit << at % 8
    assert frames.outputs == want, copy


@pytest.mark.parametrize("cnt, wkc, copied", [
    (7, 7, True), (7, 4, False), (7, -1, False),           # the ENI's Cnt decides
    (None, 3, True), (None, 0, False), (None, -1, False)])  # without: some slave answered
def test_input_data_is_valid_for_a_copy(example_plan, cnt, wkc, copied):
    """ETG.2100 CopyInfos: "copy valid input data of this command".  With a Cnt the data
    is valid at that working counter only; without one, when some slave put data in: a
    working counter of 0 means the data came back as the master sent it."""
    from ecatcfg.runtime.master.cyclic import CyclicFrames
    plan = copying.deepcopy(example_plan)
    lrw = _lrw(plan)
    lrw.cnt = cnt
    lrw.copy_infos = [CopyInfo(0, 0, 8)]
    frames = CyclicFrames(plan)
    frames.inputs[:] = bytes([0x5A]) * len(frames.inputs)
    frames.outputs[:] = bytes(len(frames.outputs))
    for p in frames.prepared(AlState.OP):
        p.bind(frames.inputs, frames.outputs, bytearray(2048))
        for s in p.slots:
            s.wkc = wkc if s.cmd is lrw else -1
        p.copy_slave_to_slave()
    assert frames.outputs[0] == (0x5A if copied else 0)


def test_compiled_copies_match_a_bit_by_bit_copy(example_plan):
    """Every placement of 1..24-bit copies (a seeded sample) against a copy made here one
    bit at a time."""
    import random
    rng = random.Random(7)
    size = 25 * 8
    for _ in range(300):
        n = rng.randint(1, 24)
        _copy_and_compare(example_plan,
                          CopyInfo(rng.randrange(size - n), rng.randrange(size - n), n), rng)


@pytest.mark.parametrize("src, dst, n", [
    (0, 72, 16), (8, 80, 24), (16, 0, 16), (80, 152, 16), (96, 8, 24), (0, 128, 8)])
def test_whole_byte_copies_of_several_bytes_match_a_bit_by_bit_copy(example_plan, src, dst,
                                                                    n):
    """Byte-aligned copies of two or three bytes (a random placement is seldom aligned),
    from and to bytes past the eighth."""
    import random
    _copy_and_compare(example_plan, CopyInfo(src, dst, n), random.Random(src * 1000 + dst))


def test_copies_over_veth(veth_netns, example_plan):
    """The same over raw Ethernet: the master on a veth end in one namespace, the emulated
    line answering on the other (tests/rig.py)."""
    from rig import serving
    from ecatcfg.esi.library import Library
    from ecatcfg.runtime.segment import emulate
    plan = with_copies(example_plan, CopyInfo(SENSORS_IN, LAMPS_OUT + 2, 4))
    seg = emulate.segment(emulate.specs_from_eni(plan, Library(ESI, cache=False), "line"))
    with serving(veth_netns, seg):
        with Network(plan, veth_netns.socket_in(veth_netns.ns_a)) as net:
            net.up()
            assert net.state == AlState.OP
            seg.slaves[2].set_inputs(b"\x0b")
            assert net.cycle()
            assert seg.slaves[3].outputs() == b"\x00"
            assert net.cycle()
            assert seg.slaves[3].outputs() == bytes([0b0010_1100])


# -- the compiler: master.copies in the topology ----------------------------------------------

TOPOLOGY = """\
master:
  name: copies
  copies:
    - {from: sensors.Channel 2.Input, to: lamps.Channel 1-8.Output 8}
    - {from: buttons.Channel 1.Input, to: lamps.Channel 1-8.Output 1}
slaves:
  - {name: coupler, device: EX1100}
  - {name: buttons, device: EX1004}
  - {name: sensors, device: EX1004}
  - {name: lamps, device: EX2008}
"""


def _compile(tmp_path, text: str):
    import subprocess
    import sys
    topo = tmp_path / "line.yaml"
    topo.write_text(text)
    eni = tmp_path / "line.eni.xml"
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "compile", str(topo), "--esi",
                           str(EXAMPLES / "esi"), "-o", str(eni), "--no-cache"],
                          capture_output=True, text=True, timeout=120)
    return topo, eni, done


def test_a_topologys_copies_are_compiled_and_applied(tmp_path, eni_schema):
    """``ecatcfg compile`` writes the copies (schema-valid); applied, the lamps show the
    sensor and the button a cycle later."""
    _, eni, done = _compile(tmp_path, TOPOLOGY)
    assert done.returncode == 0, done.stderr
    assert eni_schema.validate(etree.parse(str(eni))), eni_schema.error_log
    plan = eni_reader.read_file(eni)
    assert plan.unsupported == []
    with Network.virtual(plan, ESI, esi_cache=False) as net:
        net.up()
        net.segment.slaves[1].set_inputs(b"\x01")           # button 1
        sensors(net, 0b0010)                               # sensor 2
        assert net.cycle() and net.cycle()
        assert lamps(net) == 0b1000_0001


def test_a_topologys_wrong_copies_are_errors_at_their_lines(tmp_path):
    text = TOPOLOGY.replace("sensors.Channel 2.Input,", "sensors.Channel 2.Inputs,").replace(
        "to: lamps.Channel 1-8.Output 1}", "to: lamps.Channel 1-8.Output 9}")
    topo, eni, done = _compile(tmp_path, text)
    assert done.returncode == 1
    assert (f"{topo}:4: 'sensors.Channel 2.Inputs' is not an input variable of the process "
            "image; did you mean 'sensors.Channel 2.Input'") in done.stderr
    assert f"{topo}:5: 'lamps.Channel 1-8.Output 9' is not an output variable" in done.stderr
    assert not eni.exists()
    sizes = TOPOLOGY.replace("buttons.Channel 1.Input", "axis1.TxPDO 1 (CSP).Statusword") \
        + '  - {name: axis1, device: "0xE0000ECA:0x7201"}\n'
    topo, _, done = _compile(tmp_path, sizes)
    assert done.returncode == 1
    assert (f"{topo}:5: copy 'axis1.TxPDO 1 (CSP).Statusword' (16 bits) to "
            "'lamps.Channel 1-8.Output 1' (1 bit): the sizes differ") in done.stderr


def _compile_here(tmp_path, text: str):
    """The topology compiled in this process (``ecatcfg compile`` above runs in another):
    the plan, or the TopologyError's problems as text."""
    from ecatcfg.compiler import build, topology
    from ecatcfg.compiler.topology import TopologyError
    from ecatcfg.esi.library import Library
    topo = tmp_path / "here.yaml"
    topo.write_text(text)
    try:
        return topo, build.compile_topology(topology.load(topo),
                                            Library(ESI, cache=False)).plan
    except TopologyError as exc:
        return topo, [str(problem) for problem in exc.problems]


def test_a_topologys_copies_land_on_the_command_that_reads_them(tmp_path):
    """The example's image (module docstring): buttons inputs bits 0-3, sensors 4-7, lamps
    outputs bits 8-15; so sensor channel 2 is input bit 5, lamp output 8 is bit 15, button 1
    bit 0, lamp 1 bit 8, all on the process data LRW that reads the inputs in OP."""
    _, plan = _compile_here(tmp_path, TOPOLOGY)
    assert isinstance(plan, NetworkPlan), plan
    assert _lrw(plan).copy_infos == [CopyInfo(5, 15, 1), CopyInfo(0, 8, 1)]
    assert [c for cyc in plan.cyclic for f in cyc.frames for c in f.cmds
            if c.copy_infos] == [_lrw(plan)]


def test_a_topologys_wrong_copies_are_errors_at_their_lines_in_process(tmp_path):
    text = TOPOLOGY.replace("sensors.Channel 2.Input,", "sensors.Channel 2.Inputs,").replace(
        "to: lamps.Channel 1-8.Output 1}", "to: lamps.Channel 1-8.Output 9}")
    topo, problems = _compile_here(tmp_path, text)
    assert (f"{topo}:4: 'sensors.Channel 2.Inputs' is not an input variable of the process "
            "image; did you mean 'sensors.Channel 2.Input'") in "\n".join(problems)
    assert f"{topo}:5: 'lamps.Channel 1-8.Output 9' is not an output variable" in \
        "\n".join(problems)
    sizes = TOPOLOGY.replace("buttons.Channel 1.Input", "axis1.TxPDO 1 (CSP).Statusword") \
        + '  - {name: axis1, device: "0xE0000ECA:0x7201"}\n'
    topo, problems = _compile_here(tmp_path, sizes)
    assert problems == [f"{topo}:5: copy 'axis1.TxPDO 1 (CSP).Statusword' (16 bits) to "
                        "'lamps.Channel 1-8.Output 1' (1 bit): the sizes differ"]


def test_a_copy_written_as_a_block_is_refused_at_its_from_line(tmp_path):
    flow = "    - {from: sensors.Channel 2.Input, to: lamps.Channel 1-8.Output 8}\n"
    text = TOPOLOGY.replace(flow, "    - to: lamps.Channel 1-8.Output 8\n"
                                  "      from: sensors.Channel 2.Inputs\n")
    topo, problems = _compile_here(tmp_path, text)
    assert [p.split(": ")[0] for p in problems] == [f"{topo}:5"]


def test_an_input_no_command_reads_in_op_is_an_error_at_its_line(tmp_path):
    """The LRW that reads the sensors made to run in SAFEOP only: no command reads the
    copy's input in OP, whose copies run then (docs/runtime.md)."""
    from ecatcfg.compiler import copies, topology
    _, plan = _compile_here(tmp_path, TOPOLOGY.replace(
        "  copies:\n    - {from: sensors.Channel 2.Input, to: lamps.Channel 1-8.Output 8}\n"
        "    - {from: buttons.Channel 1.Input, to: lamps.Channel 1-8.Output 1}\n", ""))
    assert isinstance(plan, NetworkPlan), plan
    _lrw(plan).states = ["SAFEOP"]
    topo = tmp_path / "line.yaml"
    # The first copy as a block, its 'from' on line 5: the error is at that line.
    topo.write_text(TOPOLOGY.replace(
        "    - {from: sensors.Channel 2.Input, to: lamps.Channel 1-8.Output 8}\n",
        "    - to: lamps.Channel 1-8.Output 8\n      from: sensors.Channel 2.Input\n"))
    errors = copies.add_copies(topology.load(topo), plan)
    assert [str(e) for e in errors][:1] == [
        f"{topo}:5: no cyclic command reads 'sensors.Channel 2.Input' in OP"]


# -- a real TwinCAT ENI, with a copy added -----------------------------------------------------

def test_a_copy_in_a_real_twincat_eni(corpus):
    """No real ENI we have holds CopyInfos (both corpora: none), so one is added to
    TwinCAT's (EK1100, EL2008, EL4002, EL1809; a frame-shaped image: the EL1809's inputs
    at BitOffs 448 = 8·(LRD InputOffs 46 + 10), the EL2008's outputs at 344): EL1809
    channels 3-6 to EL2008 channels 4-7, on the LRD that reads them, offsets as the
    Variables give them."""
    plan = eni_reader.read_file(corpus / "eni" / "jn-ec-master" / "mega_master_eni.xml")
    inputs = {v.name: v.bit_offs for v in plan.process_image.inputs}
    outputs = {v.name: v.bit_offs for v in plan.process_image.outputs}
    src = inputs["Term 4 (EL1809).Channel 3.Input"]
    dst = outputs["Term 2 (EL2008).Channel 4.Output"]
    [lrd] = [c for cyc in plan.cyclic for f in cyc.frames for c in f.cmds if c.cmd == Cmd.LRD
             and c.cnt == 1]
    lrd.copy_infos = [CopyInfo(src, dst, 4)]
    plan = eni_reader.read_bytes(eni_writer.to_bytes(plan), "mega-copies.xml")
    assert plan.unsupported == []
    with Network.virtual(plan, [corpus / "esi" / "beckhoff"], esi_cache=False) as net:
        net.up()
        assert net.state == AlState.OP
        el1809, el2008 = net.segment.slaves[3], net.segment.slaves[1]
        el1809.set_inputs(bytes([0b0010_1100, 0]))          # channels 3, 4 and 6
        assert net.cycle()
        assert el2008.outputs() == b"\x00"
        assert net.cycle()
        assert el2008.outputs() == bytes([0b0101_1000])      # channels 4, 5 and 7
