"""The command-line contract (docs/architecture.md): exit codes, JSON shape, messages, and light
imports."""

from __future__ import annotations

import json
import subprocess

from conftest import EXAMPLES, ROOT, device_xml, esi_xml, write
from installed import ECATCFG, PYTHON
from ecatcfg.cli import SUBCOMMANDS

CONTRACT_KEYS = {"file", "line", "vendor_id", "product_code", "revision", "type", "name",
                 "group", "rx_pdos", "tx_pdos", "rx_entries", "tx_entries", "mailbox",
                 "dc_opmodes", "slots", "modules"}


def ecatcfg(*args: str, cwd=ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([*ECATCFG, *args], capture_output=True,
                          text=True, cwd=cwd)


def test_devices_json_shape_on_examples():
    out = ecatcfg("devices", "--format", "json", "examples/")
    assert out.returncode == 0, out.stderr
    devices = json.loads(out.stdout)["devices"]
    assert len(devices) == 10   # the line of examples/esi, the station, the tree (4)
    drive = next(d for d in devices if d["type"] == "EXD-402")
    assert CONTRACT_KEYS <= set(drive)
    assert drive == {**drive, "file": "examples/esi/ecatcfg-EXD402-drive.xml",
                     "vendor_id": 0xE0000ECA, "product_code": 0x7201, "revision": 0x20000,
                     "rx_pdos": 2, "tx_pdos": 2, "rx_entries": 4, "tx_entries": 4,
                     "mailbox": ["CoE", "FoE"], "dc_opmodes": ["DC", "FreeRun"], "slots": 0,
                     "modules": 0, "group": "ExDrive",
                     "name": "EXD-402 servo drive, CiA 402 (example)"}
    text = (EXAMPLES / "esi" / "ecatcfg-EXD402-drive.xml").read_text().splitlines()
    assert 'ProductCode="#x00007201"' in text[drive["line"]]   # line of <Device>, Type next


def test_devices_text_lists_selector_and_source():
    out = ecatcfg("devices", "examples")
    assert out.returncode == 0
    assert "0xe0000eca:0x7201:0x20000" in out.stdout and "10 devices in 5 files" in out.stdout


def test_missing_path_exits_2():
    out = ecatcfg("devices", "no/such/dir")
    assert out.returncode == 2 and "no/such/dir: no such file or folder" in out.stderr
    assert "Traceback" not in out.stderr


def test_usage_error_exits_2():
    out = ecatcfg("devices", "--format", "yaml", "examples")
    assert out.returncode == 2 and "invalid choice" in out.stderr
    assert ecatcfg().returncode == 2


def test_a_subcommand_parses_alone_as_in_the_whole_parser(capsys):
    """``main`` builds only the invoked subcommand's parser (startup time); its help, its
    errors and an unknown command read as with the whole command line."""
    from ecatcfg.cli import build_parser
    for name in SUBCOMMANDS:
        alone = build_parser(name)._subparsers._group_actions[0].choices[name]
        whole = build_parser()._subparsers._group_actions[0].choices[name]
        assert alone.format_help() == whole.format_help()
    out = ecatcfg("aply", "x.eni.xml")
    assert out.returncode == 2 and "invalid choice: 'aply'" in out.stderr
    assert "apply" in out.stderr and "simulate" in out.stderr      # the whole list


def test_console_flushes_everything_before_its_fast_exit(tmp_path):
    """``python -m ecatcfg`` ends with os._exit: output larger than a pipe's buffer must
    still arrive whole, and the exit code must be main's."""
    devices = [device_xml(f"FX{n}", product=f"#x{n + 1:x}") for n in range(400)]
    write(tmp_path, "many.xml", esi_xml(*devices))
    out = ecatcfg("devices", "--format", "json", "--no-cache", str(tmp_path))
    assert out.returncode == 0 and len(out.stdout) > 65536
    assert len(json.loads(out.stdout)["devices"]) == 400     # complete JSON document
    assert ecatcfg("devices", "no/such/dir").returncode == 2
    # A reader that goes away early (`| head`): exit 0, nothing on stderr, as before.
    proc = subprocess.Popen([*ECATCFG, "devices", "--format", "json",
                             "--no-cache", str(tmp_path)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, cwd=ROOT)
    proc.stdout.read(10)
    proc.stdout.close()
    assert proc.wait(30) == 0
    assert proc.stderr.read() == b""


def test_malformed_file_exits_1_naming_file_and_line(tmp_path):
    write(tmp_path, "cut.xml", esi_xml()[:300])
    write(tmp_path, "good.xml", esi_xml(device_xml("GOOD")))
    out = ecatcfg("devices", str(tmp_path))
    assert out.returncode == 1
    assert f"{tmp_path}/cut.xml:" in out.stderr and "not well-formed" in out.stderr
    assert "Traceback" not in out.stderr
    assert "GOOD" in out.stdout                         # the good file is still listed


def test_bad_product_code_exits_1_with_line(tmp_path):
    path = write(tmp_path, "bad.xml", esi_xml(device_xml(product="#xNOPE")))
    out = ecatcfg("devices", "--format", "json", str(path))
    assert out.returncode == 1
    err = json.loads(out.stdout)["errors"][0]
    assert err["file"] == str(path) and err["line"] > 1 and "#xNOPE" in err["message"]


def test_help_and_devices_do_not_import_scapy_or_the_runtime():
    probe = (
        "import sys, io, contextlib\n"
        "from ecatcfg.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    try: main(['--help'])\n"
        "    except SystemExit: pass\n"
        "    heavy_after_help = [m for m in sys.modules if m.startswith(('scapy', 'lxml', 'ecatcfg.runtime'))]\n"
        "    main(['devices', 'examples'])\n"
        "bad = [m for m in sys.modules if m.startswith(('scapy', 'ecatcfg.runtime', 'pysoem'))]\n"
        "print(heavy_after_help, bad)\n")
    out = subprocess.run([*PYTHON, "-c", probe], capture_output=True, text=True,
                         cwd=ROOT, check=True)
    assert out.stdout.strip() == "[] []"


def test_demo_compiles_the_embedded_example(tmp_path):
    out = ecatcfg("demo", cwd=tmp_path)                  # no paths, any folder
    assert out.returncode == 0, out.stderr
    assert "axis1" in out.stdout and "LRW (WKC 7)" in out.stdout
    assert (tmp_path / "ecatcfg-demo" / "demo.eni.xml").read_bytes().startswith(b"<?xml")
    assert b"#define ECAT_OUT_AXIS1" in (tmp_path / "ecatcfg-demo" / "demo.h").read_bytes()


def test_devices_of_a_folder_without_esi_files_exits_2_unless_allowed(tmp_path):
    """``devices`` of a folder with no ESI file (empty, or only an ENI) used to list "0
    devices in 0 files" and exit 0; --allow-empty keeps that."""
    write(tmp_path, "plan.xml", "<EtherCATConfig><Config/></EtherCATConfig>")
    out = ecatcfg("devices", str(tmp_path))
    assert out.returncode == 2 and out.stdout == ""
    assert f"ecatcfg devices: no ESI file in {tmp_path}: nothing was read" in out.stderr
    allowed = ecatcfg("devices", "--allow-empty", str(tmp_path))
    assert allowed.returncode == 0 and "0 devices in 0 files" in allowed.stdout
    # a broken ESI file is an input: its error, exit 1, not "no ESI file"
    write(tmp_path, "broken.xml", "<EtherCATInfo><Vendor>")
    broken = ecatcfg("devices", str(tmp_path / "broken.xml"))
    assert broken.returncode == 1 and "no ESI file" not in broken.stderr
