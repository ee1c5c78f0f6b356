"""``ecatcfg simulate``'s first words: a missing interface is refused before anything is
printed, and the slave table keeps its columns with names longer than a column (cut with an
ellipsis)."""

from __future__ import annotations

import subprocess
import sys

from conftest import EXAMPLES, write
from rig import start_simulate

ESI = EXAMPLES / "esi"
LONG = "a_coupler_with_a_name_far_longer_than_the_column"


def test_a_missing_interface_is_the_only_thing_printed(tmp_path):
    topo = write(tmp_path, "t.yaml", f"slaves:\n  - {{name: {LONG}, device: EX1100}}\n"
                                     "  - {name: io, device: EX1004}\n")
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "simulate", "--topology",
                           str(topo), "--esi", str(ESI), "--iface", "ecatnosuch0",
                           "--no-cache", "--duration", "1"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done
    assert done.stdout == ""
    assert done.stderr.startswith("ecatcfg simulate: no such network interface: "
                                  "'ecatnosuch0'"), done.stderr
    assert "Traceback" not in done.stderr


def test_a_missing_interface_comes_before_the_cut_cables_and_the_enis_notes(tmp_path):
    topo = write(tmp_path, "t.yaml", "slaves:\n  - {name: a, device: EX1100}\n"
                                     "  - {name: b, device: EX1004}\n")
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "simulate", "--topology",
                           str(topo), "--esi", str(ESI), "--iface", "ecatnosuch0",
                           "--cut", "b", "--no-cache"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done
    assert done.stdout == ""
    assert "cable into" not in done.stderr


def test_long_names_are_cut_and_the_columns_stay(veth_netns, tmp_path):
    topo = write(tmp_path, "t.yaml",
                 f"slaves:\n  - {{name: {LONG}, device: EX1100}}\n"
                 "  - {name: io, device: EX1004}\n"
                 "  - {name: exactly_16_chars, device: EX1004}\n")
    sim, lines = start_simulate(veth_netns, "--topology", str(topo), "--esi", str(ESI),
                                duration=1)
    sim.communicate(timeout=30)
    assert lines[-1].startswith("ready: 3 slaves"), lines
    header, *rows = lines[:4]
    # Written out by hand: 16 characters of name (15 and the ellipsis), then the device.
    assert rows[0].startswith("  0  a_coupler_with_\u2026 EX1100         0xe0000eca"), rows
    assert rows[1].startswith("  1  io               EX1004         0xe0000eca"), rows
    assert rows[2].startswith("  2  exactly_16_chars EX1004         0xe0000eca"), rows
    assert header.index("device") == rows[0].index("EX1100") == rows[2].index("EX1004")


def test_simulate_reports_unknown_keys_with_the_rest_before_opening_anything(tmp_path):
    topo = write(tmp_path, "t.yaml", "slaves:\n  - {name: a, device: EX1100, aliass: 3}\n"
                                     "  - {name: b, device: NOPE}\n")
    done = subprocess.run([sys.executable, "-m", "ecatcfg", "simulate", "--topology",
                           str(topo), "--esi", str(ESI), "--iface", "ecatnosuch0",
                           "--no-cache"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 1, done
    assert done.stdout == ""
    assert f"{topo}:2: slaves.0.aliass: unknown key; did you mean 'alias'?" in done.stderr
    assert f"{topo}:3: slave 'b': no device with Type name 'NOPE'" in done.stderr
