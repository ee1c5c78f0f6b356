"""``ecatcfg export --format ros2``: the generic-slave YAML files and the ros2_control
fragment it writes, read by the rules of ethercat_driver_ros2's own parser (transcribed
below from the driver archive of the corpus: its C++ needs ROS 2 and yaml-cpp, which a CI
machine does not have), configure IgH as the ENI says: for every corpus ENI the export
accepts, each slave's identity, SyncManagers, PDO assignment and mapping, start-up SDOs in
order and DC AssignActivate are what the test reads from the ENI with lxml; every ENI
variable has an interface on its entry or a comment saying why not; the fragment names
every slave in bus order with the interfaces its YAML uses.
"""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import corpus_eni, corpus_enis, plan_or_refused
from lxml import etree
from test_export_igh_c import _accepted, eni_expectations

# ec_sync_manager.hpp / ecrt.h: EC_WD_DEFAULT 0, EC_WD_ENABLE 1, EC_WD_DISABLE 2.
WATCHDOG = {"enable": 1, "disable": 2}


class DriverRefuses(AssertionError):
    """What the driver's parser would refuse or silently drop."""


def _uint(value: object, bits: int, what: str) -> int:
    """yaml-cpp ``as<uintN_t>``: an integer in range (a YAML 1.1 hex literal is one)."""
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < 1 << bits:
        raise DriverRefuses(f"{what}: {value!r} is not a uint{bits}")
    return value


def type2bits(kind: str) -> int:
    """ec_pdo_channel_manager.hpp ``type2bits`` (its uint8_t result)."""
    if kind == "bool":
        return 1
    for bits in (8, 16, 32, 64):
        if kind in (f"int{bits}", f"uint{bits}"):
            return bits
    if "bit" in kind:
        return int(kind[kind.find("bit") + 3:]) & 0xFF
    raise DriverRefuses(f"channel type {kind!r}: type2bits returns -1")


def sdo_bytes(sdo: dict) -> tuple[int, int, bytes]:
    """ec_sdo_manager.hpp ``load_from_config`` (index, sub_index, type and value, each
    required, else the entry is dropped) and ``buffer_write`` (the int value written in the
    type's size, little-endian: EC_WRITE_U8..U32)."""
    for key in ("index", "sub_index", "type", "value"):
        if key not in sdo:
            raise DriverRefuses(f"sdo {sdo}: no {key}: the driver drops it")
    value = sdo["value"]
    if not isinstance(value, int) or not -(1 << 31) <= value < 1 << 31:
        raise DriverRefuses(f"sdo value {value!r} is not an int")
    size = {"uint8": 1, "int8": 1, "uint16": 2, "int16": 2, "uint32": 4, "int32": 4}.get(
        sdo["type"])
    if size is None:
        raise DriverRefuses(f"sdo type {sdo['type']!r}: type2bytes has no size for it")
    return (_uint(sdo["index"], 16, "sdo index"), _uint(sdo["sub_index"], 8, "sub_index"),
            (value & ((1 << 8 * size) - 1)).to_bytes(size, "little"))


def load_slave(text: str) -> dict:
    """generic_ec_slave.cpp ``setup_from_config`` and ``setup_syncs``, as data."""
    config = yaml.safe_load(text)
    if not config:
        raise DriverRefuses("empty configuration")
    for key in ("vendor_id", "product_id"):
        if key not in config:
            raise DriverRefuses(f"no {key}")
    out: dict = {"vendor_id": _uint(config["vendor_id"], 32, "vendor_id"),
                 "product_id": _uint(config["product_id"], 32, "product_id"),
                 "assign_activate": _uint(config.get("assign_activate", 0), 32, "aa"),
                 "sdos": [sdo_bytes(s) for s in config.get("sdo") or []]}
    pdos: dict[str, list] = {"rpdo": [], "tpdo": []}
    interfaces: dict[str, list] = {"rpdo": [], "tpdo": []}
    for kind, key in (("rpdo", "command_interface"), ("tpdo", "state_interface")):
        for pdo in config.get(kind) or []:
            channels = []
            for c in pdo["channels"]:
                for need in ("index", "sub_index", "type"):
                    if need not in c:
                        raise DriverRefuses(f"channel {c}: no {need}")
                channels.append((_uint(c["index"], 16, "channel index"),
                                 _uint(c["sub_index"], 8, "channel sub_index"),
                                 type2bits(c["type"])))
                if c.get(key) is not None:
                    interfaces[kind].append((c[key], _uint(pdo["index"], 16, "pdo"),
                                             sum(b for _, _, b in channels[:-1]), c))
            pdos[kind].append((_uint(pdo["index"], 16, "pdo index"), channels))
    syncs = []
    for sm in config.get("sm") or []:                   # ec_sync_manager.hpp load_from_config
        if "index" not in sm or sm.get("type") not in ("input", "output"):
            raise DriverRefuses(f"sm {sm}: the driver drops it")
        which = sm.get("pdo") if sm.get("pdo") in ("rpdo", "tpdo") else None
        syncs.append((_uint(sm["index"], 8, "sm index"),
                      "out" if sm["type"] == "output" else "in",
                      WATCHDOG.get(sm.get("watchdog"), 0), pdos[which] if which else []))
    out["syncs"] = syncs
    out["interfaces"] = interfaces
    return out


def module_params(fragment: bytes) -> list[dict[str, str]]:
    """ethercat_driver.cpp ``getEcModuleParam`` over every gpio: each ec_module's name,
    plugin and params, and the gpio's interfaces (the driver numbers them in order)."""
    robot = etree.fromstring(b'<robot name="test">' + fragment.split(b"-->", 1)[1] +
                             b"</robot>")
    out = []
    for control in robot.iterchildren("ros2_control"):
        for gpio in control.iterchildren("gpio"):
            for module in gpio.iterchildren("ec_module"):
                params = {"name": module.get("name"),
                          "plugin": module.findtext("plugin")}
                params.update({p.get("name"): p.text for p in module.iterchildren("param")})
                params["command"] = [i.get("name") for i in gpio.iterchildren(
                    "command_interface")]
                params["state"] = [i.get("name") for i in gpio.iterchildren("state_interface")]
                out.append(params)
    return out


def export(eni: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ecatcfg", "export", str(eni), "--format",
                           "ros2", "-o", str(out), "--no-cache"], capture_output=True,
                          text=True, timeout=120)


def _expected_per_slave(calls: list[str]) -> list[dict]:
    slaves: list[dict] = []
    for call in calls:
        kind, *f = call.split()
        if kind == "slave_config":
            slaves.append({"vendor_id": int(f[2]), "product_id": int(f[3]),
                           "assign_activate": 0, "sdos": [], "syncs": []})
        elif kind == "sync":
            slaves[-1]["syncs"].append((int(f[1]), f[2], int(f[3]), []))
        elif kind == "pdo":
            slaves[-1]["syncs"][-1][3].append((int(f[2]), []))
        elif kind == "entry":
            slaves[-1]["syncs"][-1][3][-1][1].append((int(f[3]), int(f[4]), int(f[5])))
        elif kind == "sdo":
            slaves[-1]["sdos"].append((int(f[1]), int(f[2]), bytes.fromhex(f[3])))
        elif kind == "dc":
            slaves[-1]["assign_activate"] = int(f[1])
            slaves[-1]["dc_cycle"] = int(f[2])
    return slaves


def check_export(path: Path, fragment: bytes, files: list[tuple[str, bytes]]) -> None:
    calls, variables = eni_expectations(path)
    want = _expected_per_slave(calls)
    params = module_params(fragment)
    assert [int(p["position"]) for p in params] == list(range(len(want)))
    assert [p["slave_config"] for p in params] == [name for name, _ in files]
    frequency = float(re.search(rb'name="control_frequency">([^<]+)<', fragment).group(1))
    texts = {name: data.decode() for name, data in files}
    for position, (w, p) in enumerate(zip(want, params)):
        assert p["plugin"] == "ethercat_generic_plugins/GenericEcSlave"
        got = load_slave(texts[p["slave_config"]])
        for key in ("vendor_id", "product_id", "assign_activate", "sdos", "syncs"):
            assert got[key] == w[key], (path, position, key)
        if "dc_cycle" in w:          # the driver's SYNC0 cycle is its control period
            assert round(1e9 / frequency) == w["dc_cycle"]
        # every interface the YAML uses is declared by the gpio, once
        assert [i[0] for i in got["interfaces"]["rpdo"]] == p["command"]
        assert [i[0] for i in got["interfaces"]["tpdo"]] == p["state"]
        assert len(set(p["command"])) == len(p["command"])
        assert len(set(p["state"])) == len(p["state"])
        # a bool's mask is its bit in its byte: IgH lays each SM's data from a byte
        start = {pdo: sum(b for _q, entries in pdos[:k] for _i, _s, b in entries)
                 for _i, _d, _w, pdos in w["syncs"] for k, (pdo, _e) in enumerate(pdos)}
        for kind in ("rpdo", "tpdo"):
            for _name, pdo, bit, channel in got["interfaces"][kind]:
                if channel["type"] == "bool":
                    assert channel["mask"] == 1 << (start[pdo] + bit) % 8, (path, channel)
        # each ENI variable of this slave: an interface on its entry, or a comment why not
        placed = {(pdo, bit) for kind in ("rpdo", "tpdo")
                  for _name, pdo, bit, _c in got["interfaces"][kind]}
        flat = " ".join(texts[p["slave_config"]].split())
        for name, pos, pdo, bit in variables:
            if pos == position and (pdo, bit) not in placed:
                assert f"not an interface: {' '.join(name.split())} (" in flat, (path, name)


def test_every_accepted_corpus_eni_configures_the_driver_as_the_eni_says(corpus,
                                                                         corpus_extra):
    from ecatcfg.eni.export import ros2
    from ecatcfg.eni.export.steps import ExportError
    checked = 0
    for path in sorted([*corpus.glob("eni/**/*.xml"), *corpus_extra.glob("eni/**/*.xml")]):
        config = _accepted(path)
        if config is None:
            continue                          # refused for IgH: test_export_igh_c
        try:
            fragment, files = ros2.render(config, str(path), "ethercat", path.name,
                                          "0" * 64, "test")
        except ExportError:
            continue                          # refused for the driver: the sweep below
        check_export(path, fragment, files)
        checked += 1
    assert checked >= 15


def test_the_command_writes_the_fragment_and_the_slaves_beside_it(corpus, tmp_path):
    eni = corpus / "eni" / "acontis-ecmaster-demo-motion" / "Yaskawa_SGDV_1ms.xml"
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        done = export(eni, tmp_path / folder / "robot.ros2_control.xml")
        assert done.returncode == 0, done.stderr
    a = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert a == ["robot.ros2_control.xml", "robot.ros2_control_0_drive-1-sgdv-e1-coe-drive.yaml"]
    for name in a:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    digest = hashlib.sha256(eni.read_bytes()).hexdigest()
    text = (tmp_path / "a" / a[1]).read_text()
    assert f"from {eni.name}, sha256 {digest}." in text
    files = [(a[1], (tmp_path / "a" / a[1]).read_bytes())]
    check_export(eni, (tmp_path / "a" / a[0]).read_bytes(), files)
    got = load_slave(text)
    # the drive's statusword (a tpdo channel) is a state interface named after the variable
    assert got["interfaces"]["tpdo"][0][0] == "2nd-transmit-pdo-mapping.status-word"


@pytest.mark.parametrize("eni", corpus_enis())
def test_every_corpus_eni_exports_for_ros2_or_is_refused_by_name(request, eni):
    from ecatcfg.eni.export import ros2
    from ecatcfg.eni.export.igh import igh_config
    from ecatcfg.eni.export.steps import ExportError
    path = corpus_eni(request, eni)
    plan = plan_or_refused(path)
    if plan is None:
        return
    try:
        fragment, files = ros2.render(igh_config(plan, path), str(path), "x", path.name,
                                      "0" * 64, "t")
    except ExportError as exc:
        assert exc.file == str(path)
        assert exc.line is not None or "master" in exc.message or plan.unsupported
        assert "slave" in exc.message or "master" in exc.message
        return
    assert len(files) == len(plan.slaves)
    for _name, data in files:
        load_slave(data.decode())


def test_what_the_driver_cannot_be_told_is_refused_by_name(corpus, corpus_extra, tmp_path):
    """SoE writes, and a DC SYNC1 cycle (the driver gives IgH no SYNC1): refused naming
    the slave, nothing written."""
    from test_export_igh_c import _add_soe, _edited, _soe
    eni = _edited(corpus, tmp_path, _add_soe(_soe(["PS"], 0, 32, "0b00")))
    done = export(eni, tmp_path / "soe.xml")
    assert done.returncode == 1
    assert re.search(r":\d+: slave 0 \('Slave_1001 \[EC-Training Sampler\]'\): SoE write "
                     r"S-0-0032 \(drive 0\) = 0b 00: the driver's generic slave has no SoE",
                     done.stderr), done.stderr
    assert list(tmp_path.glob("soe*")) == []
    drive = corpus_extra / "eni" / "pmec-wec-bench" / "DriveMotorXML.xml"
    done = export(drive, tmp_path / "drive.xml")
    assert done.returncode == 1
    assert "SYNC1 cycle 100000 ns: the driver gives ecrt_slave_config_dc" in done.stderr
